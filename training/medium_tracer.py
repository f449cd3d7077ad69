"""Photon tracer in an infinite homogeneous medium, tabulating double and multiple scattering (Ge et al.,
"Interactive Simulation of Scattering Effects in Participating Media Using a Neural Network Model", Secs. 3.2-3.7).

Units and medium. Lengths are in mean free paths (sigma_t = 1); ``alpha`` = sigma_s / sigma_t is the albedo and
``g`` the Henyey-Greenstein mean cosine (``addon.reference.hg``). A point source at the origin emits unit power
along +z (a point-directional light; a real light's virtual ray light is a line of them).

Events. Photons fly Exp(1) distances. The k-th collision is the k-th scattering event; the weight *arriving* at
collision k is alpha^(k-1) (absorption is carried as weight; each scattering draws a new direction from HG about
the current one). Let C_k(x, w') be the density of k-th collisions per unit volume and per unit solid angle of
the arrival direction w' (the direction of propagation of the flight that ends at x), weighted by alpha^(k-1),
per unit source power. What is tabulated is

    Phi_k(x, w) = alpha * Integral p(w' . w) C_k(x, w') dw'

the radiance emitted per unit volume into the direction of propagation w at x by k-th scattering events, per
unit source power: the in-scattered source term *including the final phase function* (p is HG with the
propagation convention, so g > 0 scatters forward). A camera ray x(s) = x0 - s w seeing light that travels
along w gathers Integral T(s) Phi(x(s), w) ds. Tables: ``double`` = Phi_2, ``multiple`` = Sum_{k>=3} Phi_k;
Phi_1 (single scattering, which the renderer computes itself) is kept for tests only. Integrated over w, Phi_k
is alpha times the weighted collision density, which the tables also carry (``density_*``, per unit volume).

Coordinates (the paper's Fig. 2). Cylindrical about the source axis: rho >= 0 and z. Directions are expressed in
the local frame (e_rho, e_phi, e_z) of the point: theta from +z, phi the azimuth from e_rho. The problem is
symmetric under the mirror across the plane holding the axis and the point (phi -> -phi), so phi is folded to
[0, pi]. Collisions exactly on the axis (the first collisions; measure zero afterwards) use e_rho = +x.

Grid (``Grid``, ``default_grid``). Cells in rho and z have sinh spacing: edges s * sinh(u * asinh(R / s)) for u
uniform, which is uniform (about 0.16 mfp) near the source and geometric (about 16 % of the distance) far away.
Default R = 256 mfp (z in [-256, 256], 80 cells; rho in [0, 256], 40 cells), s = 1 mfp; directions in 18 x 18
bins of 10 degrees (theta 0-180, phi 0-180), Phi sampled at the bin centres. Why not the paper's grids: Sec. 3.4
(24 mfp, 100 uniform samples of rho and z) and Sec. 4.2 (32 mfp, one sample per mfp) disagree, and both are
too short for high albedo. The diffusion length 1 / sqrt(3 (1 - alpha)(1 - alpha g)) is 18 mfp for alpha = 0.999,
g = 0 (milk) and 82 mfp for g = 0.95; with Phi ~ exp(-r / L) / r the share of the scattered energy beyond R is
(1 + R / L) exp(-R / L): about half beyond 32 mfp for milk, 0.7 % beyond 256 mfp (g = 0), 18 % for g = 0.95
(the worst corner; ``captured`` in the tables reports the measured share inside: 87 % of the orders >= 3 for
alpha = 0.999, g = 0.95, all but 3e-6 for alpha = 0.999, g = 0). The sinh grid reaches 256 mfp
with 3200 spatial cells (the paper's Sec. 3.4 grid has 10000 over 24 mfp) and is finer than 0.5 mfp within
3 mfp of the source, where double scattering and strong forward scattering have their structure.

Estimator. Every collision of order k inside the table adds its weight to H[group, rho, z, theta', phi'] (the cell
of the collision and the arrival-direction bin in its local frame; np.bincount on flattened indices, groups
1, 2, >= 3). The phase function is applied once at the end:

    Phi[rho, z, theta, phi] = alpha * Sum_bins P[theta', phi'; theta, phi] H[rho, z, theta', phi'] / (N V_cell)

with V_cell = pi (rho1^2 - rho0^2)(z1 - z0) and P = p(w' . w) at the output bin centre w, averaged over
sub-samples of the arrival bin that are uniform in solid angle (``sub`` x ``sub`` stratified midpoints in
cos theta' and phi') and over its mirror (-phi'). This assumes the arrival directions uniform within a 10-degree
bin: the tables are smoothed by the bins, as the paper's are. Standard errors come from independent batches.

Russian roulette (unbiased). All photons of a batch reach collision k together, so weights are one number per
order. Collision k is reached with probability P_k = min(1, alpha^(k-1) / w_rr) and carries weight
alpha^(k-1) / P_k: photons keep their whole weight alpha^(k-1) until it falls below w_rr (``roulette``), then
survive each further scattering with probability alpha at weight w_rr. The expected weight at every order is
exactly alpha^(k-1); only its noise and cost change. The default w_rr = alpha^2 (every photon reaches the third
collision, the first of the multiple table, at full weight; analog absorption after it) was measured against
w_rr = 1 (analog), 0.25 and alpha^4 at equal collision budgets (alpha 0.3, 0.7, 0.95, g = 0.5; median relative
standard error of the multiple table): its standard error is within 12 % of the best everywhere, while analog's
is 2.5x larger at alpha = 0.3 and a fixed 0.25's 1.4x larger at alpha = 0.3 and 1.13x at 0.95 (a fixed low w_rr
also costs ln(1 / w_rr) / (1 - alpha) extra collisions at high albedo).

Far photons. A photon whose collision lies farther than ``far`` from the source (default 4 R = 1024 mfp, well
beyond the table corner at 362 mfp: 8 diffusion lengths of the slowest-decaying material) is dropped after that
collision is counted. Its later collisions are lost: those that would have come back into the table are the only
bias left. ``trace(..., probe=True)`` keeps such photons and tallies separately what they add to the table after
crossing ``far``, which measures it. Default grid, alpha = 0.999, g = 0.95 (the slowest decay), 1e5 photons:
5 crossed 1024 mfp and none of their later collisions came back into the table (probe weight 0 of 8.7e7 in the
table). The probe does see the bias when the bound is tight: on the tests' small grid (corner 6.4 mfp) with
alpha = 0.99, g = 0 (diffusion length 5.8 mfp) it is 17 % of the in-table weight for far = 1.01 x corner, 1.5 %
at 2x and nothing measurable at 4x (3000 photons; tests/unit/test_medium_tracer.py checks that the probe sees
the loss at 1.01x and that 4x removes most of it). For alpha = 1 the bound is what ends the walks, the bias is about
r / far at distance r (diffusion with an absorbing sphere), and the cost grows as far^2: albedo 1 is supported
for tests on small grids, not in the default dataset.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from addon.reference import hg

GROUPS = ("single", "double", "multiple")  # orders 1, 2 and >= 3


# ------------------------------------------------------------------------------------------ grid

def sinh_edges(extent: float, n: int, scale: float) -> np.ndarray:
    """n + 1 edges from 0 to ``extent``: uniform (about scale * asinh(extent / scale) / n) near 0, geometric far."""
    u = np.linspace(0.0, math.asinh(extent / scale), n + 1)
    e = scale * np.sinh(u)
    e[-1] = extent
    return e


@dataclass(frozen=True)
class Grid:
    """Table cells: edges in rho (from 0) and z (mfp), and the number of theta and folded-phi bins over [0, pi]."""
    rho_edges: tuple
    z_edges: tuple
    n_theta: int = 18
    n_phi: int = 18

    def __post_init__(self):
        r, z = np.asarray(self.rho_edges, float), np.asarray(self.z_edges, float)
        if r[0] != 0.0 or np.any(np.diff(r) <= 0) or np.any(np.diff(z) <= 0) or len(r) < 2 or len(z) < 2:
            raise ValueError("rho edges must start at 0 and both edge lists must increase")
        if self.n_theta < 1 or self.n_phi < 1:
            raise ValueError("direction bins must be at least 1")

    @property
    def shape(self):
        return (len(self.rho_edges) - 1, len(self.z_edges) - 1, self.n_theta, self.n_phi)

    @property
    def n_space(self) -> int:
        return (len(self.rho_edges) - 1) * (len(self.z_edges) - 1)

    @property
    def n_dir(self) -> int:
        return self.n_theta * self.n_phi

    @property
    def corner(self) -> float:
        """Largest distance from the source to a point of the table."""
        return math.hypot(self.rho_edges[-1], max(abs(self.z_edges[0]), abs(self.z_edges[-1])))

    def volumes(self) -> np.ndarray:
        """(n_rho, n_z) cell volumes pi (rho1^2 - rho0^2)(z1 - z0)."""
        r, z = np.asarray(self.rho_edges), np.asarray(self.z_edges)
        return np.pi * np.outer(np.diff(r * r), np.diff(z))

    def theta_centres(self) -> np.ndarray:
        return (np.arange(self.n_theta) + 0.5) * np.pi / self.n_theta

    def phi_centres(self) -> np.ndarray:
        return (np.arange(self.n_phi) + 0.5) * np.pi / self.n_phi

    def to_json(self) -> dict:
        return {"rho_edges": [float(v) for v in self.rho_edges], "z_edges": [float(v) for v in self.z_edges],
                "n_theta": self.n_theta, "n_phi": self.n_phi}


def default_grid(extent: float = 256.0, n_rho: int = 40, n_z: int = 80, scale: float = 1.0, n_theta: int = 18,
                 n_phi: int = 18) -> Grid:
    """The dataset's grid: rho in [0, extent] (n_rho cells), z in [-extent, extent] (n_z cells, half on each side),
    sinh spacing with ``scale`` (mfp) near the source; direction bins of 180 / n degrees."""
    if n_z % 2:
        raise ValueError("n_z must be even (half the cells on each side of the source)")
    r = sinh_edges(extent, n_rho, scale)
    half = sinh_edges(extent, n_z // 2, scale)
    z = np.concatenate([-half[::-1], half[1:]])
    return Grid(tuple(r.tolist()), tuple(z.tolist()), n_theta, n_phi)


# ------------------------------------------------------------------------------------------ sampling

def scatter(directions: np.ndarray, g: float, rng: np.random.Generator) -> np.ndarray:
    """New unit propagation directions drawn from HG(g) about the unit rows ``directions``."""
    n = len(directions)
    return hg.sample(g, directions, rng.random(n), rng.random(n))


def _local_bins(pos, d, grid: Grid, theta_step, phi_step):
    """Flat direction-bin index of the arrival directions ``d`` in the local frames of the points ``pos``."""
    x, y = pos[:, 0], pos[:, 1]
    a = d[:, 0] * x + d[:, 1] * y  # rho * (d . e_rho)
    b = d[:, 1] * x - d[:, 0] * y  # rho * (d . e_phi)
    on_axis = (x == 0.0) & (y == 0.0)
    if on_axis.any():
        a = np.where(on_axis, d[:, 0], a)
        b = np.where(on_axis, d[:, 1], b)
    theta = np.arccos(np.clip(d[:, 2], -1.0, 1.0))
    phi = np.abs(np.arctan2(b, a))
    it = np.minimum((theta / theta_step).astype(np.int64), grid.n_theta - 1)
    ip = np.minimum((phi / phi_step).astype(np.int64), grid.n_phi - 1)
    return it * grid.n_phi + ip


@dataclass
class Tallies:
    """What ``trace`` accumulates for ``photons`` photons.

    ``hist``: (3, n_space, n_dir) weighted collisions inside the table by group (orders 1, 2, >= 3), cell and
    arrival bin; ``order_weight[k - 1]`` / ``order_count[k - 1]``: total weight and number of collisions of order
    k everywhere (inside the table or not); ``dropped``: photons dropped beyond ``far`` and ``dropped_weight``
    the weight they carried at that collision; ``probe``: (3,) in-table weight added after crossing ``far``
    (only with probe=True, when nothing is dropped); ``crossed``: photons that went beyond ``far``."""
    photons: int
    hist: np.ndarray
    order_weight: np.ndarray = field(default_factory=lambda: np.zeros(0))
    order_count: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    dropped: int = 0
    dropped_weight: float = 0.0
    probe: np.ndarray = field(default_factory=lambda: np.zeros(3))
    crossed: int = 0

    def add_order(self, k: int, weight: float, count: int):
        if len(self.order_weight) < k:
            grow = max(k, 2 * len(self.order_weight))
            self.order_weight = np.concatenate([self.order_weight, np.zeros(grow - len(self.order_weight))])
            self.order_count = np.concatenate([self.order_count,
                                               np.zeros(grow - len(self.order_count), np.int64)])
        self.order_weight[k - 1] += weight * count
        self.order_count[k - 1] += count

    def trimmed(self):
        k = int(np.max(np.nonzero(self.order_count)[0], initial=-1)) + 1
        self.order_weight, self.order_count = self.order_weight[:k], self.order_count[:k]
        return self


class _Buffer:
    """Flat indices and weights per group, bincounted into ``hist`` in large blocks (cheap tails)."""

    def __init__(self, hist, limit=1 << 22):
        self.hist, self.limit = hist.reshape(3, -1), limit
        self.idx, self.w, self.size = [[], [], []], [[], [], []], 0

    def add(self, group, idx, weight):
        if len(idx):
            self.idx[group].append(idx)
            self.w[group].append(np.full(len(idx), weight))
            self.size += len(idx)
            if self.size >= self.limit:
                self.flush()

    def flush(self):
        n = self.hist.shape[1]
        for gi in range(3):
            if self.idx[gi]:
                self.hist[gi] += np.bincount(np.concatenate(self.idx[gi]), np.concatenate(self.w[gi]), minlength=n)
            self.idx[gi], self.w[gi] = [], []
        self.size = 0


def default_roulette(alpha: float) -> float:
    """w_rr = alpha^2: the whole weight up to the third collision, analog absorption after it."""
    return alpha * alpha


def roulette_schedule(alpha: float, roulette: float):
    """Yield (weight w_k, survival probability from k to k + 1) for k = 1, 2, ...: P_k = min(1, alpha^(k-1) / w_rr),
    w_k = alpha^(k-1) / P_k (``roulette`` = w_rr = 0: no roulette). The survival is 0 once the weight is 0."""
    a_pow, p = 1.0, 1.0
    while True:
        w = a_pow / p
        nxt = a_pow * alpha
        if nxt <= 0.0:
            yield w, 0.0
            return
        p_next = 1.0 if roulette <= 0.0 or nxt >= roulette else nxt / roulette
        yield w, p_next / p
        a_pow, p = nxt, p_next


def expected_collisions(alpha: float, roulette: float | None = None, max_order: int | None = None) -> float:
    """Expected collisions per photon, Sum_k P_k (walks ended by ``far`` aside; inf when nothing else ends them)."""
    roulette = default_roulette(alpha) if roulette is None else roulette
    total, p, k = 0.0, 1.0, 0
    for _, survive in roulette_schedule(alpha, roulette):
        k += 1
        total += p  # P_k
        if (max_order is not None and k >= max_order) or survive <= 0.0:
            return total
        if p < 1.0 and max_order is None:  # in the roulette: survival alpha per step from here on
            return total + p * alpha / (1.0 - alpha)
        if k >= 10**6:
            return math.inf
        p *= survive
    return total


def trace(alpha: float, g: float, grid: Grid, photons: int, rng: np.random.Generator, *, max_order: int | None = None,
          roulette: float | None = None, far: float | None = None, probe: bool = False,
          chunk: int = 1 << 16) -> Tallies:
    """Trace ``photons`` photons from the point-directional source; see the module docstring.

    ``max_order``: stop after that collision (None: no limit); ``roulette``: w_rr (default alpha^2; 0: none, needs
    max_order); ``far``: drop bound
    (default 4 x the table's half-width, at least 1.5 x its corner); ``probe``: do not drop, measure instead."""
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"albedo must be in [0, 1], got {alpha}")
    if not -1.0 < g < 1.0:
        raise ValueError(f"g must be in (-1, 1), got {g}")
    far = default_far(grid) if far is None else float(far)
    if far < grid.corner:
        raise ValueError(f"the far bound {far} must lie beyond the table (corner at {grid.corner:.3g} mfp)")
    roulette = default_roulette(alpha) if roulette is None else float(roulette)
    if roulette <= 0.0 and max_order is None and alpha > 0.0:
        raise ValueError("without roulette the walks need max_order")
    if alpha >= 1.0 and max_order is None and (probe or not math.isfinite(far)):
        raise ValueError("albedo 1 needs a finite far bound (without probe) or max_order to end the walks")
    tallies = Tallies(photons, np.zeros((3, grid.n_space, grid.n_dir)))
    buf = _Buffer(tallies.hist)
    for start in range(0, photons, chunk):
        _trace_chunk(alpha, g, grid, min(chunk, photons - start), rng, max_order, roulette, far, probe, tallies, buf)
    buf.flush()
    return tallies.trimmed()


def default_far(grid: Grid) -> float:
    half = max(grid.rho_edges[-1], abs(grid.z_edges[0]), abs(grid.z_edges[-1]))
    return max(4.0 * half, 1.5 * grid.corner)


def _trace_chunk(alpha, g, grid, n, rng, max_order, roulette, far, probe, tallies, buf):
    rho_e, z_e = np.asarray(grid.rho_edges), np.asarray(grid.z_edges)
    n_rho, n_z = len(rho_e) - 1, len(z_e) - 1
    theta_step, phi_step = np.pi / grid.n_theta, np.pi / grid.n_phi
    pos = np.zeros((n, 3))
    d = np.tile([0.0, 0.0, 1.0], (n, 1))
    crossed = np.zeros(n, bool)
    far2 = far * far
    k = 0
    for w, survive in roulette_schedule(alpha, roulette):
        k += 1
        pos += rng.standard_exponential(len(pos))[:, None] * d
        tallies.add_order(k, w, len(pos))
        group = min(k, 3) - 1
        r2 = np.einsum("ij,ij->i", pos, pos)
        beyond = r2 > far2
        rho = np.hypot(pos[:, 0], pos[:, 1])
        ir = np.searchsorted(rho_e, rho, side="right") - 1
        iz = np.searchsorted(z_e, pos[:, 2], side="right") - 1
        inside = (ir < n_rho) & (iz >= 0) & (iz < n_z)
        if inside.any():
            sel = np.nonzero(inside)[0]
            flat = (ir[sel] * n_z + iz[sel]) * grid.n_dir + _local_bins(pos[sel], d[sel], grid, theta_step, phi_step)
            buf.add(group, flat, w)
            if probe and crossed.any():
                tallies.probe[group] += w * np.count_nonzero(crossed[sel])
        if probe:
            tallies.crossed += int(np.count_nonzero(beyond & ~crossed))
            crossed |= beyond
            keep = np.ones(len(pos), bool)
        else:
            keep = ~beyond
            n_drop = len(pos) - int(np.count_nonzero(keep))
            tallies.dropped += n_drop
            tallies.crossed += n_drop
            tallies.dropped_weight += w * n_drop
        if (max_order is not None and k >= max_order) or survive <= 0.0:
            break
        if survive < 1.0:
            keep &= rng.random(len(pos)) < survive
        if not keep.all():
            pos, d, crossed = pos[keep], d[keep], crossed[keep]
        if len(pos) == 0:
            break
        d = scatter(d, g, rng)


# ------------------------------------------------------------------------------------------ emission

def phase_matrix(g: float, grid: Grid, sub: int = 16) -> np.ndarray:
    """(n_dir arrival bins, n_dir output directions): HG p(w' . w) at the output bin centres w, averaged over
    ``sub`` x ``sub`` midpoints uniform in solid angle of each arrival bin and of its mirror (-phi')."""
    th_e = np.linspace(0.0, np.pi, grid.n_theta + 1)
    ph_e = np.linspace(0.0, np.pi, grid.n_phi + 1)
    frac = (np.arange(sub) + 0.5) / sub
    # arrival sub-samples: cos theta' uniform within each theta bin, phi' uniform within each phi bin
    c0, c1 = np.cos(th_e[:-1]), np.cos(th_e[1:])
    cos_in = c0[:, None] + (c1 - c0)[:, None] * frac[None, :]  # (n_theta, sub)
    phi_in = ph_e[:-1, None] + (ph_e[1:] - ph_e[:-1])[:, None] * frac[None, :]  # (n_phi, sub)
    sin_in = np.sqrt(np.maximum(0.0, 1.0 - cos_in * cos_in))
    th_out, ph_out = grid.theta_centres(), grid.phi_centres()
    cos_out, sin_out = np.cos(th_out), np.sin(th_out)
    out = np.empty((grid.n_theta, grid.n_phi, grid.n_theta, grid.n_phi))
    for jt in range(grid.n_theta):
        for jp in range(grid.n_phi):
            # cos between w' = (sin' cos phi', sin' sin phi', cos') and w; the mirror flips sin phi'
            dphi_cos = np.cos(phi_in - ph_out[jp])  # (n_phi, sub)
            dphi_mir = np.cos(phi_in + ph_out[jp])
            base = (cos_in * cos_out[jt])[:, :, None, None]
            ss = (sin_in * sin_out[jt])[:, :, None, None]
            p1 = hg.eval(g, np.clip(base + ss * dphi_cos[None, None], -1.0, 1.0))
            p2 = hg.eval(g, np.clip(base + ss * dphi_mir[None, None], -1.0, 1.0))
            out[:, :, jt, jp] = 0.5 * (p1.mean(axis=(1, 3)) + p2.mean(axis=(1, 3)))
    return out.reshape(grid.n_dir, grid.n_dir)


def emission(hist: np.ndarray, alpha: float, grid: Grid, photons: int, phase: np.ndarray) -> np.ndarray:
    """Phi (n_rho, n_z, n_theta, n_phi) from one group's (n_space, n_dir) weighted collision histogram."""
    vol = grid.volumes().reshape(-1, 1)
    return (alpha * (hist @ phase) / (photons * vol)).reshape(grid.shape)


def density(hist: np.ndarray, grid: Grid, photons: int) -> np.ndarray:
    """Weighted collision density per unit volume (n_rho, n_z), all arrival directions together."""
    return hist.sum(axis=1).reshape(grid.shape[:2]) / (photons * grid.volumes())


# ------------------------------------------------------------------------------------------ one material

@dataclass(frozen=True)
class Settings:
    """Photon counts and estimator settings of one material's tables (all batches together)."""
    photons: int = 20000  # full walks (all orders): the multiple table
    double_photons: int = 2_000_000  # walks cut after collision 2: the double table (pooled with the full walks)
    batches: int = 8  # independent batches: the standard errors
    roulette: float | None = None  # default_roulette(alpha)
    far: float | None = None  # default_far(grid)
    sub: int = 16  # phase-matrix sub-samples per arrival bin and axis

    def __post_init__(self):
        if self.batches < 2 or self.photons < self.batches or self.double_photons < 0:
            raise ValueError("need at least 2 batches and one full photon per batch")


def simulate(alpha: float, g: float, grid: Grid | None = None, settings: Settings = Settings(), seed: int = 0,
             progress=None) -> dict:
    """Tables of one material: ``double`` and ``multiple`` (Phi, grid.shape) with ``*_se`` standard errors from
    independent batches, ``single`` (Phi_1, tests only), ``density_*`` (n_rho, n_z) weighted collision densities
    per group with ``*_se``, per-order totals, captured shares and the time taken (s)."""
    grid = grid or default_grid()
    start = time.perf_counter()
    phase = phase_matrix(g, grid, settings.sub)
    children = np.random.SeedSequence(seed).spawn(settings.batches)
    sums, squares = {}, {}
    order_w, order_n = np.zeros(0), np.zeros(0, np.int64)
    in_table = np.zeros(3)
    dropped = crossed = 0
    dropped_weight = 0.0
    for b, child in enumerate(children):
        rng = np.random.default_rng(child)
        n_full = settings.photons // settings.batches + (b < settings.photons % settings.batches)
        n_short = settings.double_photons // settings.batches + (b < settings.double_photons % settings.batches)
        full = trace(alpha, g, grid, n_full, rng, roulette=settings.roulette, far=settings.far)
        short = trace(alpha, g, grid, n_short, rng, max_order=2, roulette=0.0, far=settings.far) if n_short else None
        h1 = full.hist[0] + (short.hist[0] if short else 0.0)
        h2 = full.hist[1] + (short.hist[1] if short else 0.0)
        n12 = n_full + n_short
        values = {"single": emission(h1, alpha, grid, n12, phase), "double": emission(h2, alpha, grid, n12, phase),
                  "multiple": emission(full.hist[2], alpha, grid, n_full, phase),
                  "density_single": density(h1, grid, n12), "density_double": density(h2, grid, n12),
                  "density_multiple": density(full.hist[2], grid, n_full)}
        for key, v in values.items():
            sums[key] = sums.get(key, 0.0) + v
            squares[key] = squares.get(key, 0.0) + v * v
        k = max(len(order_w), len(full.order_weight))
        order_w = np.pad(order_w, (0, k - len(order_w))) + np.pad(full.order_weight, (0, k - len(full.order_weight)))
        order_n = np.pad(order_n, (0, k - len(order_n))) + np.pad(full.order_count, (0, k - len(full.order_count)))
        in_table += full.hist.sum(axis=(1, 2))
        dropped += full.dropped
        crossed += full.crossed
        dropped_weight += full.dropped_weight
        if progress:
            progress(b + 1, settings.batches)
    nb = settings.batches
    result = {}
    for key in sums:
        mean = sums[key] / nb
        var = np.maximum(squares[key] / nb - mean * mean, 0.0) * nb / (nb - 1)
        result[key] = mean
        result[key + "_se"] = np.sqrt(var / nb)
    total = np.array([order_w[:1].sum(), order_w[1:2].sum(), order_w[2:].sum()])
    result.update({
        "order_weight": order_w / settings.photons,  # mean weight per photon at order k (index k - 1)
        "order_count": order_n,
        # share inside the table (clipped: the two sums differ by rounding)
        "captured": np.minimum(1.0, np.divide(in_table, total, out=np.zeros(3), where=total > 0)),
        "dropped": dropped, "dropped_weight": dropped_weight / settings.photons,
        "seconds": time.perf_counter() - start,
    })
    return result
