"""Monte Carlo ground truth ("g.t.") of the anisotropic layered stack (paper anisotropic_layered; model
models.aniso_stack): a position-free random walk through the explicit stack (pbrt-v4's LayeredBxDF and Guo et al.
2018's position-free Monte Carlo, extended to N interfaces, each in its own tangent frame), against which the
analytic adding loop (reference.aniso_stack, not imported here) is measured.

Simulated physics (directions are unit rows in the local shading frame: z the macro normal, x the surface tangent):

- Layers 0..N top down: air (IOR 1) above interface 0; layer j + 1 between interfaces j and j + 1 holds media[j];
  below a dielectric last interface lies a semi-infinite dielectric of its IOR (light entering it is transmitted),
  a conductor ends the stack. Position-free: a path only carries its depth z below the top of its layer.
- Interface j is a single-scattering Smith microsurface: anisotropic GGX with (alpha_x, alpha_y) along its own
  tangent, the surface tangent rotated by ``rotation`` degrees about z. In that frame D(m) = 1 / (pi ax ay (mx^2 /
  ax^2 + my^2 / ay^2 + mz^2)^2), Lambda(w) = (sqrt(1 + (ax^2 wx^2 + ay^2 wy^2) / wz^2) - 1) / 2, and the
  height-correlated G2 = 1 / (1 + Lambda(wi) + Lambda(wo)) for reflection and refraction alike (reference.microfacet,
  pbrt-v4 and Cycles do the same; reference.aniso_stack_tables integrates the same G2). Seen from below, the
  microsurface is mirrored in z. Light that the Smith model masks after a facet interaction is lost (no
  microfacet multiple scattering): a rough non-absorbing stack returns less than 1 (``ground_truth_albedo``'s
  "masked" is that share).
- Fresnel, exact and per RGB channel: a dielectric with the relative IOR n_beyond / n_arriving of the absolute IORs
  of the layers on either side; a conductor with its complex IOR (n + ik) divided by the IOR of the medium above
  it (the model's n, k are given in air).
- RGB IORs: a per-channel walk. Where every dielectric IOR is grey, one row per path carries RGB weights (directions
  do not depend on the channel); otherwise each path is three rows, one per channel, each with its channel's IORs
  and a one-hot weight (exact dispersion; no hero-channel reweighting).
- Media: Beer-Lambert with sigma_t = sigma_a + sigma_s per channel. Where sigma_s > 0 the walk draws free flights
  from the mixture over channels of exp(sigma_t) weighted by the path's current RGB throughput (spectral MIS: every
  channel unbiased) and scatters with Henyey-Greenstein of mean cosine g; a pure absorber attenuates by
  exp(-sigma_a depth / |wz|); depth 0 or sigma_t 0 is a clear gap.

Transport conventions. The walk carries flux: light arrives from wo, and every sampled interaction multiplies the
throughput by f |cos o| / pdf(o) with f the radiance BSDF (Walter 2007 Eq. 21 for refraction, whose eta_o^2 factor
makes it flux conserving): a visible normal drawn for the arriving side, reflection with probability F (always for
a conductor, weight F), refraction otherwise, and the weight G2 / G1(arriving) (0 on the wrong side). There is no
other eta^2 factor, so reflected + transmitted + absorbed + masked = 1. Point values use reciprocity (the stack is
seen from air on both sides: f(wi, wo) = f(wo, wi)): wi is the viewer of the flux walk started at wo.

Estimator of f(wi, wo) (BSDF without cosine, RGB, both directions above):

- Order 0, the top interface's reflection from air, is the closed form F D G2 / (4 |wi_z| |wo_z|) (stderr 0).
- Every other path (wo ... wi) has a unique last scattering vertex V: a reflection from above at an interface
  j >= 1, or a medium scattering in a layer l >= 1; after V it only refracts upwards through the interfaces above
  and leaves towards wi (turning downwards again would need another scattering vertex). The walk from wo samples
  the prefix up to V (it is forced to refract at the top, weight 1 - F, and continues after every vertex, so each V
  of each path is visited; sampled exits count nothing). At V a chain sampled from the other end supplies the
  suffix, as Guo et al. connect a camera and a light subpath in the same layer: from wi downwards through
  interfaces 0 .. l - 1 into the layer l holding V, a visible normal for the chain's side and a refraction at each
  (a fresh chain per connection). The chain transports importance (wi is the viewer), so each refraction weighs
  f(x, u) |cos x| / pdf(x) = (n_u / n_x)^2 (1 - F) G2 / G1(u), u on the viewer's side and x beyond; the
  (n_u / n_x)^2 telescope to 1 / n_l^2 (n_0 = 1), the radiance compression of layer l, applied once. The layers
  crossed in full attenuate by exp(-sigma_t depth / |y_z|). The contribution is

      throughput(V) * f_V(v, -y) * exp(-tau(V) / |y_z|) * chain(y) / n_l^2,

  y the chain's direction in layer l, v = -(the walk's direction at V): at an interface f_V is its reflection
  BRDF (symmetric, so which side is "light" does not matter) and tau the whole layer's sigma_t depth; in a medium
  f_V is the HG phase function of the two propagation directions, tau = sigma_t z, and the position-free measure
  dz / |y_z| divides by |y_z| (as pbrt-v4's LayeredBxDF: no cosine at a phase-function connection).
- Unbiased: the path integral is the sum over V of (prefix density sampled by the walk) x f_V x (suffix integral);
  the suffix integral over the chain's directions y_1..y_l is estimated by one chain drawn with a density that is
  positive wherever its integrand is (a refraction of wi's side exists through a facet visible from that side iff
  light can refract back through it; total internal reflection and the wrong side carry zero in both). Distinct
  vertices of one walk and their chains are correlated, which leaves the expectation of the sum unchanged.
  Russian roulette (after ROULETTE_START vertices, survival max(RGB throughput), survivors divided by it) is
  unbiased; the one bias is truncation: orders above ``bounces`` are dropped (``ground_truth_albedo`` reports the
  throughput still travelling there as "truncated").
- Order k: the number of scattering vertices below the top surface (reflections at any interface from either side
  but the top's reflection from air, and medium scatterings) in the path: order 0 is the top interface's
  reflection, order 1 a single reflection at a deeper interface (or one medium scattering), and so on.
- f is zero for wi below the surface (transmission into the semi-infinite dielectric is measured as energy only,
  by ``ground_truth_albedo``).

Variance: a near-specular vertex BRDF evaluated towards a chain direction is near-delta (unbiased, but noisy; there
is no second strategy to weigh it against), as is every point value of a stack whose interfaces are all
near-smooth: use ``ground_truth_albedo`` for the energies of smooth stacks. Estimates are float64, vectorised over
paths (loops over interaction steps, interfaces and layers), deterministic given the seed; standard errors come
from independent batches. Cost (one core, a rough coat over gold): ~2e5 paths/s with sampled exits, ~5e5
(path, wi) pairs/s for point values (~1e5 paths/s for a single wi).
"""
from __future__ import annotations

import math

import numpy as np

from ..models.aniso_stack import params_from_dict
from . import hg, lobes
from .frames import as_directions, dot, normalize, reflect
from .microfacet import fresnel_conductor, fresnel_dielectric, ggx_d, sample_vndf, smith_lambda
from .montecarlo import batches, mean_stderr, transmittance, view_direction
from .warping import refract

__all__ = ["ndf", "smith_lambda_aniso", "sample_visible_normals", "interface_reflection", "ground_truth",
           "ground_truth_albedo", "exit_lobes"]

N_BATCHES = 8
BOUNCES = 256  # highest order traced (scattering vertices below the top surface)
ROULETTE_START = 8  # vertices before Russian roulette
NEE_PAIRS = 1 << 17  # (path, wi) pairs per vectorised connection block
MAX_EXIT_SAMPLES = 1_000_000  # exit directions kept per order by ground_truth_albedo (memory bound)
_MIRROR_Z = np.array([1.0, 1.0, -1.0])


# ------------------------------------------------------------------------------------------ anisotropic GGX

def _stretch(alpha_x, alpha_y):
    return np.array([alpha_x, alpha_y, 1.0])


def ndf(m, alpha_x, alpha_y):
    """Anisotropic GGX D(m) in the interface's frame: the alpha = 1 GGX of the stretched m / (ax, ay, 1) over ax ay."""
    return ggx_d(m / _stretch(alpha_x, alpha_y), 1.0) / (alpha_x * alpha_y)


def smith_lambda_aniso(w, alpha_x, alpha_y):
    """Anisotropic GGX Lambda in the interface's frame: the alpha = 1 Lambda of w (ax, ay, 1); inf at grazing."""
    return smith_lambda(w * _stretch(alpha_x, alpha_y), 1.0)


def sample_visible_normals(v, alpha_x, alpha_y, u1, u2):
    """Visible normals of anisotropic GGX for rows v above the interface (its frame): Heitz 2018's sampler run on
    the stretched configuration (the view stretched by (ax, ay, 1), the normal by the same factors back)."""
    s = _stretch(alpha_x, alpha_y)
    return normalize(sample_vndf(normalize(v * s), 1.0, u1, u2) * s)


def _shadowing_ratio(v, o, alpha):
    """G2(v, o) / G1(v) = (1 + Lambda(v)) / (1 + Lambda(v) + Lambda(o)): the weight of a direction o drawn through
    v's visible normals; 0 where o is grazing."""
    lam_v, lam_o = smith_lambda_aniso(v, *alpha), smith_lambda_aniso(o, *alpha)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = 1.0 / (1.0 + lam_o / (1.0 + lam_v))
    return np.where(np.isfinite(ratio), ratio, 0.0)


# ------------------------------------------------------------------------------------------ the stack

def _frame(rotation_deg):
    """Rows: the interface's tangent, bitangent and normal in the local frame (w @ frame.T: its coordinates)."""
    c, s = math.cos(math.radians(rotation_deg)), math.sin(math.radians(rotation_deg))
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


class _Stack:
    """The stack's numbers as arrays: absolute IORs per layer and channel, interface frames, media per layer."""

    def __init__(self, p):
        self.interfaces = p.interfaces
        self.n = len(p.interfaces)
        ior = np.ones((self.n + 1, 3))
        for j, interface in enumerate(p.interfaces):
            if interface.type == "dielectric":
                ior[j + 1] = interface.ior
        self.ior = ior  # (N + 1, 3); below a conductor: unused
        grey = bool(np.all(ior == ior[:, :1]))
        self.row_ior = ior[:, :1].T if grey else ior.T  # (channel groups, N + 1): the IORs a row walks with
        self.row_weight = np.ones((1, 3)) if grey else np.eye(3)  # a row's initial RGB weight per group
        self.frames = [_frame(i.rotation) for i in p.interfaces]
        self.alphas = [(i.alpha_x, i.alpha_y) for i in p.interfaces]
        self.depth = np.zeros(self.n + 1)
        self.sigma_t = np.zeros((self.n + 1, 3))
        self.sigma_s = np.zeros((self.n + 1, 3))
        self.g = np.zeros(self.n + 1)
        for l, medium in enumerate(p.media, start=1):
            self.depth[l], self.g[l] = medium.depth, medium.g
            self.sigma_s[l] = medium.sigma_s
            self.sigma_t[l] = np.add(medium.sigma_a, medium.sigma_s)
        self.tau = self.sigma_t * self.depth[:, None]  # optical depth along the normal per layer
        self.scattering = [l for l in range(1, self.n) if self.depth[l] > 0.0 and np.any(self.sigma_s[l] > 0.0)]
        self.absorbing = [l for l in range(1, self.n) if l not in self.scattering and np.any(self.tau[l] > 0.0)]

    def fresnel(self, j, cos, n_near, n_far):
        """(n, 3) reflectance at interface j for facet cosines cos (n,) on the side of absolute IOR n_near (n_far
        beyond); the IORs are (n, 1) (a row's channel) or (1, 3) (every channel)."""
        interface = self.interfaces[j]
        if interface.type == "conductor":
            return fresnel_conductor(cos, np.asarray(interface.ior) / n_near, np.asarray(interface.k) / n_near)
        cos, eta = np.broadcast_arrays(cos[:, None], n_far / n_near)
        return np.broadcast_to(fresnel_dielectric(cos, eta), (len(cos), 3))


def _params(p):
    """A Params, or an Anisotropic Stack dict read by the model's declaration."""
    return params_from_dict(p) if isinstance(p, dict) else p


def _reflection(stack, j, v, o, n_above, n_below):
    """f_r = F D(h) G2 / (4 |v_z| |o_z|) of interface j for local rows v, o above it, (n, 3); 0 unless both above."""
    frame, alpha = stack.frames[j], stack.alphas[j]
    vi, oi = v @ frame.T, o @ frame.T
    h = normalize(vi + oi)
    above = (v[:, 2] > 0.0) & (o[:, 2] > 0.0)
    g2 = 1.0 / (1.0 + smith_lambda_aniso(vi, *alpha) + smith_lambda_aniso(oi, *alpha))
    value = ndf(h, *alpha) * g2 / (4.0 * np.where(above, v[:, 2] * o[:, 2], 1.0))
    return np.where(above[:, None], stack.fresnel(j, dot(vi, h), n_above, n_below) * value[:, None], 0.0)


def interface_reflection(p, j, wi, wo):
    """The closed-form reflection BRDF of interface j seen from the layer above it (order 0 for j = 0), RGB
    (n, 3): F D(h) G2 / (4 |wi_z| |wo_z|) with the exact Fresnel per channel; rows wi, wo in the local frame."""
    stack = _Stack(_params(p))
    wi, wo = np.broadcast_arrays(as_directions(wi), as_directions(wo))
    return _reflection(stack, j, wi, wo, stack.ior[j][None, :], stack.ior[j + 1][None, :])


def _scatter(stack, j, v, n_near, n_far, u, transmit_only=False):
    """Light arriving at interface j from the side of the local rows v (pointing away from the interface), absolute
    IORs n_near there and n_far beyond ((n, 1) per row); u (n, 3) uniforms. A visible normal for v, then reflection
    (probability F; always for a conductor, weighted by F) or refraction; ``transmit_only`` always refracts,
    weighted by 1 - F. Returns the new propagation directions (local), the throughput factor (n, 3), the share of
    the throughput lost to masking-shadowing (n, 3) and whether each row reflected."""
    frame, alpha = stack.frames[j], stack.alphas[j]
    flip = np.where((v[:, 2] < 0.0)[:, None], _MIRROR_Z, 1.0)
    vi = (v * flip) @ frame.T
    m = sample_visible_normals(vi, *alpha, u[:, 1], u[:, 2])
    fres = stack.fresnel(j, dot(vi, m), n_near, n_far)
    if stack.interfaces[j].type == "conductor":
        reflected, branch = np.ones(len(v), dtype=bool), fres
    elif transmit_only:
        reflected, branch = np.zeros(len(v), dtype=bool), 1.0 - fres
    else:
        reflected, branch = u[:, 0] < fres[:, 0], np.ones_like(fres)
    t, refracts = refract(vi, m, (n_far / n_near)[:, 0])
    o = np.where(reflected[:, None], reflect(vi, m), normalize(t))
    good = np.where(reflected, o[:, 2] > 0.0, refracts & (o[:, 2] < 0.0))
    shadow = np.where(good, _shadowing_ratio(vi, o, alpha), 0.0)[:, None]
    return (o @ frame) * flip, branch * shadow, branch * (1.0 - shadow), reflected


# ------------------------------------------------------------------------------------------ the walk

class _Paths:
    """The live rows of a walk: per-row layer IORs, RGB throughput, propagation direction, layer, depth in the
    layer, order so far and the interface that reflected last (-1: none)."""

    FIELDS = ("ior", "w", "d", "layer", "z", "events", "last")

    def __init__(self, stack, wo, n):
        group = np.repeat(np.arange(len(stack.row_ior)), n)
        self.ior, self.w = stack.row_ior[group], stack.row_weight[group]
        self.d = np.tile(-wo, (len(group), 1))
        self.layer = np.zeros(len(group), dtype=int)
        self.z = np.zeros(len(group))
        self.events = np.zeros(len(group), dtype=int)
        self.last = np.full(len(group), -1)

    def keep(self, mask):
        for name in self.FIELDS:
            setattr(self, name, getattr(self, name)[mask])


class _Tally:
    """What a walk deposits: sampled exits per side as (directions, weights, orders, last reflectors) blocks, the
    throughput masked by the microsurfaces and the throughput still travelling when an order passed ``bounces``."""

    def __init__(self):
        self.exits = {"reflection": [], "transmission": []}
        self.masked = np.zeros(3)
        self.truncated = np.zeros(3)

    def exit(self, side, paths, rows):
        if rows.size:
            self.exits[side].append((paths.d[rows], paths.w[rows], paths.events[rows], paths.last[rows]))


def _free_flight(stack, l, d, z, w, u_channel, u_distance):
    """One free flight in scattering layer l from depth z along d (spectral MIS over channels, module docstring).
    Returns whether it scattered, the new throughput and the new depth (the boundary's where it did not)."""
    sigma_t, sigma_s, depth = stack.sigma_t[l], stack.sigma_s[l], stack.depth[l]
    down = d[:, 2] < 0.0
    to_boundary = np.where(down, depth - z, z) / np.abs(d[:, 2])
    q = w / w.sum(axis=1, keepdims=True)
    channel, _, _ = lobes.choose(q, u_channel)
    rate = sigma_t[channel]
    with np.errstate(divide="ignore"):
        s = np.where(rate > 0.0, -np.log1p(-u_distance) / np.where(rate > 0.0, rate, 1.0), np.inf)
    scattered = s < to_boundary
    s = np.where(scattered, s, to_boundary)
    tr = np.exp(-sigma_t * s[:, None])
    density = np.where(scattered[:, None], sigma_t * tr, tr)  # collision density / passing probability
    norm = np.sum(q * density, axis=1, keepdims=True)
    gain = np.where(scattered[:, None], sigma_s * tr, tr)
    w = np.divide(w * gain, norm, out=np.zeros_like(w), where=norm > 0.0)
    return scattered, w, np.where(scattered, z - s * d[:, 2], np.where(down, depth, 0.0))


def _walk(stack, wo, n, rng, bounces, connections=None):
    """n paths (per channel group) of light arriving from wo; with ``connections`` the top refracts always and every
    vertex connects to the viewer directions (module docstring). Returns the walk's _Tally."""
    paths, tally = _Paths(stack, wo, n), _Tally()
    while len(paths.d):
        u = rng.random((len(paths.d), 6))  # flight: 0, 1; phase function or interface: 2, 3, 4; roulette: 5
        alive = np.isfinite(paths.d[:, 2]) & (paths.d[:, 2] != 0.0)
        at_interface = alive.copy()
        for l in stack.scattering:
            rows = np.flatnonzero(alive & (paths.layer == l))
            scattered, paths.w[rows], paths.z[rows] = _free_flight(stack, l, paths.d[rows], paths.z[rows],
                                                                   paths.w[rows], u[rows, 0], u[rows, 1])
            rows = rows[scattered]
            at_interface[rows] = False
            over = paths.events[rows] >= bounces
            tally.truncated += paths.w[rows[over]].sum(axis=0)
            alive[rows[over]] = False
            rows = rows[~over]
            paths.events[rows] += 1
            if connections is not None:
                connections.medium_vertex(l, paths, rows)
            paths.d[rows] = hg.sample(stack.g[l], paths.d[rows], u[rows, 2], u[rows, 3])
        for l in stack.absorbing:
            rows = np.flatnonzero(alive & (paths.layer == l))
            paths.w[rows] *= transmittance(stack.tau[l], paths.d[rows, 2])
        down = paths.d[:, 2] < 0.0
        interface = np.where(down, paths.layer, paths.layer - 1)
        for j in range(stack.n):
            for from_above in (True, False):
                rows = np.flatnonzero(at_interface & (interface == j) & (down == from_above))
                if rows.size:
                    _interact(stack, j, from_above, paths, rows, u[rows, 2:5], tally, alive, bounces, connections)
        tally.exit("reflection", paths, np.flatnonzero(alive & (paths.layer == 0)))
        tally.exit("transmission", paths, np.flatnonzero(alive & (paths.layer == stack.n)))
        alive &= (paths.layer > 0) & (paths.layer < stack.n) & np.any(paths.w > 0.0, axis=1)
        _roulette(paths, alive, u[:, 5])
        paths.keep(alive)
    return tally


def _interact(stack, j, from_above, paths, rows, u, tally, alive, bounces, connections):
    """Rows arriving at interface j (from above or below): connect (from above, j >= 1), then sample it."""
    near, far = (j, j + 1) if from_above else (j + 1, j)
    entering = from_above and j == 0  # the first interaction, from air: its reflection is order 0
    if connections is not None and from_above and j > 0:
        connections.interface_vertex(j, paths, rows[paths.events[rows] < bounces])
    d, w_in = paths.d[rows], paths.w[rows]
    d, factor, masked, reflected = _scatter(stack, j, -d, paths.ior[rows, near:near + 1],
                                            paths.ior[rows, far:far + 1], u,
                                            transmit_only=entering and connections is not None)
    paths.d[rows], paths.w[rows] = d, w_in * factor
    tally.masked += np.sum(w_in * masked, axis=0)
    turned = rows[reflected]
    paths.last[turned] = j
    if not entering:
        over = turned[paths.events[turned] >= bounces]
        tally.truncated += paths.w[over].sum(axis=0)
        alive[over] = False
        paths.events[turned] += 1
    crossed = rows[~reflected]
    paths.layer[crossed] = far
    paths.z[crossed] = 0.0 if from_above else stack.depth[far]


def _roulette(paths, alive, u):
    """Russian roulette after ROULETTE_START vertices: survival probability max(RGB throughput) (capped at 1),
    survivors divided by it."""
    rows = np.flatnonzero(alive & (paths.events >= ROULETTE_START))
    q = np.minimum(paths.w[rows].max(axis=1), 1.0)
    survive = u[rows] < q
    alive[rows[~survive]] = False
    paths.w[rows[survive]] /= q[survive, None]


# ------------------------------------------------------------------------------------------ connections

def _chain(stack, wi, ior, layer, rng):
    """Viewer chains from the air directions wi (rows) down to ``layer`` (>= 1) through interfaces 0 .. layer - 1,
    each a sampled refraction (module docstring). Returns the directions in ``layer`` (propagation, downwards) and
    the chain weights (k, 3): the (1 - F) G2 / G1 of each refraction, the transmittance of the layers crossed in
    full, and the radiance factor 1 / n_layer^2."""
    y, weight = -wi, np.ones((len(wi), 3))
    for j in range(layer):
        if j:
            weight = weight * transmittance(stack.tau[j], y[:, 2])
        y, factor, _, _ = _scatter(stack, j, -y, ior[:, j:j + 1], ior[:, j + 1:j + 2], rng.random((len(y), 3)),
                                   transmit_only=True)
        weight = weight * factor
    return y, weight / ior[:, layer:layer + 1] ** 2


class _Connections:
    """Next-event connections of a walk to fixed viewer directions wi (above): per order k, the sum over paths of
    their contributions to f_k(wi, wo) (module docstring)."""

    def __init__(self, stack, wi, bounces, rng):
        self.stack, self.wi, self.rng = stack, wi, rng
        self.f = np.zeros((bounces + 1, len(wi), 3))

    def interface_vertex(self, j, paths, rows):
        """Rows about to meet interface j >= 1 from above (layer j): its reflection towards the chain, which then
        crosses the whole of layer j."""
        v = -paths.d[rows]
        ior = paths.ior[rows]
        tau = self.stack.tau[j]

        def value(pair, y):
            return (_reflection(self.stack, j, v[pair], -y, ior[pair, j:j + 1], ior[pair, j + 1:j + 2])
                    * transmittance(tau, y[:, 2]))

        self._connect(j, paths, rows, paths.events[rows] + 1, value)

    def medium_vertex(self, l, paths, rows):
        """Rows that just scattered at depth z in layer l (their order counted): the phase function towards the
        chain, attenuated over z, per unit depth (1 / |y_z|)."""
        d, z = paths.d[rows], paths.z[rows]
        sigma_t, g = self.stack.sigma_t[l], self.stack.g[l]

        def value(pair, y):
            phase = hg.eval(g, dot(d[pair], -y))
            return (phase / np.abs(y[:, 2]))[:, None] * transmittance(sigma_t * z[pair, None], y[:, 2])

        self._connect(l, paths, rows, paths.events[rows], value)

    def _connect(self, layer, paths, rows, order, value):
        """Add throughput * value(pair, y) * chain weight per (row, wi) pair into f[order] (chunked over rows)."""
        m = len(self.wi)
        chunk = max(1, NEE_PAIRS // m)
        for start in range(0, len(rows), chunk):
            block = np.arange(start, min(start + chunk, len(rows)))
            pair = np.repeat(block, m)
            y, chain = _chain(self.stack, np.tile(self.wi, (len(block), 1)), paths.ior[rows[pair]], layer, self.rng)
            contribution = (chain * value(pair, y)).reshape(len(block), m, 3) * paths.w[rows[block], None, :]
            for k in np.unique(order[block]):
                self.f[k] += contribution[order[block] == k].sum(axis=0)


# ------------------------------------------------------------------------------------------ public estimators

def ground_truth(p, wi, wo, n_paths=20000, seed=0, n_batches=N_BATCHES, bounces=BOUNCES):
    """Per-order BSDF f_k(wi, wo) of the stack (module docstring; k = 0..bounces) and standard errors, each shaped
    (bounces + 1, M, 3). wo (3,) above; rows wi (M, 3): f[0] is the top interface's exact reflection (stderr 0),
    f[k >= 1] next-event estimates over n_paths walks from wo in n_batches independent batches; zero for wi below."""
    p, wo = _params(p), view_direction(wo)
    stack = _Stack(p)
    wi = normalize(as_directions(wi))
    up = wi[:, 2] > 0.0
    per_batch = []
    for size, rng in batches(n_paths, n_batches, seed):
        est = np.zeros((bounces + 1, len(wi), 3))
        if up.any():
            connections = _Connections(stack, wi[up], bounces, rng)
            _walk(stack, wo, size, rng, bounces, connections)
            est[:, up] = connections.f / size
        per_batch.append(est)
    f, stderr = mean_stderr(per_batch)
    f[0, up] = interface_reflection(p, 0, wi[up], wo)
    stderr[0, up] = 0.0
    return f, stderr


def _sampled_walks(p, wo, n_paths, seed, n_batches, bounces):
    """(paths per batch, _Tally) of independent batches of walks from wo, exits sampled."""
    p, wo = _params(p), view_direction(wo)
    stack = _Stack(p)
    return [(size, _walk(stack, wo, size, rng, bounces)) for size, rng in batches(n_paths, n_batches, seed)]


def _per_order(blocks, bounces):
    """Exit energy per order (bounces + 1, 3) of a list of exit blocks."""
    out = np.zeros((bounces + 1, 3))
    for _, w, order, _ in blocks:
        np.add.at(out, order, w)
    return out


def ground_truth_albedo(p, wo, n_paths=20000, seed=0, n_batches=N_BATCHES, bounces=BOUNCES,
                        max_exit_samples=MAX_EXIT_SAMPLES):
    """Per-order directional albedo (flux leaving per unit flux arriving from wo) with sampled exits.

    Returns a dict: "reflection" (bounces + 1, 3) (order 0: the top surface, by sampling), "transmission"
    (bounces + 1, 3) (into the semi-infinite dielectric below a dielectric last interface; zeros under a
    conductor), "masked" (3,) (lost to the microsurfaces' masking-shadowing: the single-scattering Smith model's
    loss), "truncated" (3,) (still travelling past ``bounces``), "stderr": {"reflection", "transmission", "masked",
    "truncated"} of the same shapes, "exits": {"reflection", "transmission"}, per order a (directions (K, 3),
    weights (K, 3)) pair of exit samples (the first max_exit_samples of them; transmitted directions point down
    into the dielectric), and "n_paths" (the paths traced). Reflected + transmitted + masked + truncated + absorbed
    = 1 per channel."""
    names = ("reflection", "transmission")
    energies = {name: [] for name in (*names, "masked", "truncated")}
    samples = {name: [[] for _ in range(bounces + 1)] for name in names}
    kept = {name: np.zeros(bounces + 1, dtype=int) for name in names}
    total = 0
    for size, tally in _sampled_walks(p, wo, n_paths, seed, n_batches, bounces):
        total += size
        energies["masked"].append(tally.masked / size)
        energies["truncated"].append(tally.truncated / size)
        for name in names:
            energies[name].append(_per_order(tally.exits[name], bounces) / size)
            for d, w, order, _ in tally.exits[name]:
                for k in np.unique(order):
                    room = max(0, int(max_exit_samples) - kept[name][k])
                    sel = order == k
                    samples[name][k].append((d[sel][:room], w[sel][:room]))
                    kept[name][k] += min(room, int(sel.sum()))
    out = {"stderr": {}, "exits": {}, "n_paths": total}
    for name, per_batch in energies.items():
        out[name], out["stderr"][name] = mean_stderr(per_batch)
    for name in names:
        out["exits"][name] = [(np.concatenate([d for d, _ in s] + [np.zeros((0, 3))]),
                               np.concatenate([w for _, w in s] + [np.zeros((0, 3))])) for s in samples[name]]
    return out


def _lobe_sums(blocks, select):
    """Energy-weighted moments of the projected exit directions (x, y) of the exits with select(order, last):
    sum w (3,), sum w p (3, 2), sum w p p^T (3, 2, 2)."""
    s0, s1, s2 = np.zeros(3), np.zeros((3, 2)), np.zeros((3, 2, 2))
    for d, w, order, last in blocks:
        keep = select(order, last)
        xy, w = d[keep, :2], w[keep]
        s0 += w.sum(axis=0)
        s1 += w.T @ xy
        s2 += np.einsum("nc,ni,nj->cij", w, xy, xy)
    return s0, s1, s2


def _lobe_statistics(s0, s1, s2, size):
    """Energy per path, mean (3, 2) and covariance (3, 2, 2) from the moment sums (NaN where no energy)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s1 / s0[:, None]
        cov = s2 / s0[:, None, None] - mean[:, :, None] * mean[:, None, :]
    return s0 / size, mean, cov


def exit_lobes(p, wo, n_paths=20000, seed=0, n_batches=N_BATCHES, bounces=BOUNCES):
    """Exit lobe statistics of the light arriving from wo: the energy per channel and the energy-weighted mean and
    covariance of the reflected directions projected on the surface plane (local (x, y): x the surface tangent).

    Returns {"all": stats, "interfaces": [stats of the paths whose last reflection was at interface j, j = 0..N-1],
    "medium": stats of the paths that left with no interface reflection (medium scattering only), "n_paths"}, each
    stats a dict "energy" (3,), "mean" (3, 2), "cov" (3, 2, 2) (pooled over all paths; NaN where no energy) and
    "stderr" of the three (from the spread of independent batches)."""
    walks = _sampled_walks(p, wo, n_paths, seed, n_batches, bounces)
    n_interfaces = len(_params(p).interfaces)
    selectors = {"all": lambda order, last: np.ones(len(order), dtype=bool),
                 **{j: (lambda order, last, j=j: last == j) for j in range(n_interfaces)},
                 "medium": lambda order, last: last == -1}
    total = sum(size for size, _ in walks)
    out = {"n_paths": total}
    for key, select in selectors.items():
        sums = [_lobe_sums(tally.exits["reflection"], select) for _, tally in walks]
        pooled = _lobe_statistics(*(sum(s[i] for s in sums) for i in range(3)), total)
        per_batch = [_lobe_statistics(*s, size) for s, (size, _) in zip(sums, walks)]
        errors = [mean_stderr([b[i] for b in per_batch])[1] for i in range(3)]
        out[key] = {"energy": pooled[0], "mean": pooled[1], "cov": pooled[2],
                    "stderr": {"energy": errors[0], "mean": errors[1], "cov": errors[2]}}
    out["interfaces"] = [out.pop(j) for j in range(n_interfaces)]
    return out
