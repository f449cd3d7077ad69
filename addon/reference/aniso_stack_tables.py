"""The numerically integrated tables of the anisotropic stack (``reference.aniso_stack``), built by

    python -m addon.reference.aniso_stack_tables

which rewrites ``data/aniso_stack_fgd.npz`` (deterministically: same arrays, same bytes; 194 KB) and prints the
measured errors quoted here. Isotropic GGX of roughness α, height-correlated Smith G2, single scattering, μ the
cosine of incidence; each value integrated by Gauss rules over the slope CDF and two azimuth segments per slope
(``reflection_nodes``: good to ~1e-4). Float32 arrays, read by bilinear interpolation in (μ, α) after linear
interpolation along the IOR axis (``Tables``, clamped at the axes' ends):

* ``albedo[μ, α]`` (32 × 32): the directional albedo E(μ, α) = ∫ D G2 / (4 μ) dωo of the Fresnel-free GGX BRDF.
* ``fresnel_rule[μ, α]`` (32 × 32 × 3): the two-node Gauss rule (c1, c2, w1) of the albedo-weighted distribution
  of i·h over that lobe. A conductor's FGD is E (w1 F(c1) + (1 − w1) F(c2)) with its exact Fresnel F (a 4-D
  conductor table would not fit; F at the mean cosine alone was measured 4× worse).
* ``fgd[μr, α, η]`` (32 × 32 × 33): FGD(μ, α, η) = ∫ F(i·h, η) D G2 / (4 μ) dωo of a dielectric of relative IOR
  η = η_below / η_above ∈ [1/3, 3], total internal reflection included (F = 1 on facets past the critical angle).
* ``escape[μr, α, η]`` (32 × 32 × 17): for light leaving a denser medium (η < 1), the share of its visible
  microfacets (Heitz's VNDF) on which it refracts rather than being totally reflected; 1 for η ≥ 1.

Axes: μ and α by their square roots, uniform (μ ∈ [0, 1], integrated at 1e-7 for 0; α ∈ [1e-4, 1]). η: below 1,
the critical cosine sqrt(1 − η²) uniform from its value at η = 1/3 down to 0 (16 cells, dense near η = 1 where
the TIR region moves fastest); above 1, sqrt(s), s = (η − 1) / (η + 1), uniform up to sqrt(1/2) (16 cells, dense
near η = 1 where the grazing Fresnel changes fastest with η). For η < 1 the cosine axis is μr, the cosine on the
rarer side (the refracted cosine, 0 at the critical angle): the smooth Fresnel is then the same function of μr on
both sides of η = 1. Incidences past the critical angle, which the mean path of a stack seen from air never
reaches (η_j sin θ_j = sin θo), clamp to μr = 0.

Measured by the script (lookups against fresh integration at 2000 random points uniform in the axes'
coordinates; max abs error, RMS): ``albedo`` 0.031, 1.5e-3 (max 2.6e-3 for μ ≥ 0.05: the worst cells are at
μ < α, where masking shapes E within a cell); ``fgd`` 0.13, 4.4e-3 (0.017 for μr ≥ 0.05; the worst at grazing
incidence on nearly index-matched interfaces, |η − 1| < 0.003); ``escape`` 0.10, 4.3e-3 (0.044 for μr ≥ 0.05).
At the cosines and IORs the mean paths of stacks meet (views from air, absolute IORs in [1.0001, 3]): ``fgd``
0.018, 2.0e-3; ``escape`` 0.012, 1.9e-3. The conductor's Gauss rule
against its integrated FGD (n ∈ [0.01, 10], k ∈ [0, 20]): 0.16, 0.014; for metals (k ≥ 1) 0.028, 4.0e-3.

Against the Fresnel at the view's cosine (the authors' code, after Unity's StackLit: F(μ) for the FGD), on a
uniform (μr, α) grid over the IOR nodes: for η ≥ 1, F(μ) differs from FGD by up to 0.85 (RMS 0.19; at grazing
views of rough interfaces, where masking takes most of the light) and from FGD / E, the mean Fresnel over the
lobe that our lobe weights carry, by up to 0.85 (RMS 0.18); for α ≤ 0.3 and μ ≥ 0.2, by 0.22 and 0.19 (RMS 0.034
and 0.026). For η < 1 (rough facets totally reflect before the mean direction does) the differences reach 0.84
and 0.81 (RMS 0.16, 0.18), and 0.33 and 0.40 for α ≤ 0.3, μr ≥ 0.2.
"""
from __future__ import annotations

import io
import zipfile
from functools import lru_cache
from pathlib import Path
from typing import NamedTuple

import numpy as np

from . import microfacet

DATA = Path(__file__).parent / "data" / "aniso_stack_fgd.npz"
COS_NODES, ALPHA_NODES, HALF = 32, 32, 16  # the IOR axis: HALF cells below η = 1, HALF above
ETA_NODES, ESCAPE_NODES = 2 * HALF + 1, HALF + 1
MIN_ALPHA, MIN_COS = 1e-4, 1e-7  # the α axis starts at MIN_ALPHA; incidences are integrated at MIN_COS at least
MAX_S = 0.5  # s = (η − 1) / (η + 1) ≤ 0.5: η ≤ 3
MAX_CRITICAL_COS = np.sqrt(8.0 / 9.0)  # the critical cosine of η = 1/3
SPLIT_NODES, AZIMUTH_NODES = 128, 32  # quadrature: over the slope CDF, over each of two azimuth segments


# ------------------------------------------------------------------------------------------- axes

def cos_coord(mu):
    """Fractional index on the cosine axis."""
    return np.sqrt(np.clip(mu, 0.0, 1.0)) * (COS_NODES - 1)


def alpha_coord(alpha):
    """Fractional index on the roughness axis (clamped to it)."""
    lo = np.sqrt(MIN_ALPHA)
    return (np.sqrt(np.clip(alpha, MIN_ALPHA, 1.0)) - lo) / (1.0 - lo) * (ALPHA_NODES - 1)


def cos_nodes():
    return np.linspace(0.0, 1.0, COS_NODES) ** 2


def alpha_nodes():
    return np.linspace(np.sqrt(MIN_ALPHA), 1.0, ALPHA_NODES) ** 2


def eta_coord(eta):
    """Fractional index on the IOR axis: the critical cosine sqrt(1 − η²) falling uniformly from its value at
    η = 1/3 to 0 over the first ``HALF`` cells (η < 1), then sqrt(s), s = (η − 1) / (η + 1), rising uniformly to
    sqrt(1/2)."""
    eta = np.asarray(eta, dtype=float)
    below = (1.0 - np.sqrt(np.maximum(1.0 - eta * eta, 0.0)) / MAX_CRITICAL_COS) * HALF
    above = (1.0 + np.sqrt(np.maximum((eta - 1.0) / (eta + 1.0), 0.0) / MAX_S)) * HALF
    return np.clip(np.where(eta < 1.0, below, above), 0.0, 2 * HALF)


def eta_nodes(count):
    """The relative IORs of the first ``count`` nodes of the IOR axis."""
    return eta_nodes_at(np.arange(count))


def eta_nodes_at(i):
    """The relative IORs at fractional indices ``i`` of the IOR axis (the inverse of ``eta_coord``)."""
    critical = MAX_CRITICAL_COS * np.maximum(1.0 - i / HALF, 0.0)
    s = MAX_S * np.maximum(i / HALF - 1.0, 0.0) ** 2
    return np.where(i <= HALF, np.sqrt(1.0 - critical * critical), (1.0 + s) / (1.0 - s))


def rarer_cos(mu, eta):
    """μr: the cosine on the rarer side of the interface: μ itself for η ≥ 1, else the refracted cosine (0 past
    the critical angle)."""
    refracted = np.sqrt(np.maximum(1.0 - (1.0 - mu * mu) / (eta * eta), 0.0))
    return np.where(eta >= 1.0, mu, refracted)


def denser_cos(mu_rare, eta):
    """The incidence μ from the side above whose cosine on the rarer side is μr: the inverse of ``rarer_cos``."""
    return np.where(eta >= 1.0, mu_rare, np.sqrt(np.maximum(1.0 - (1.0 - mu_rare * mu_rare) * eta * eta, 0.0)))


# ------------------------------------------------------------------------------------------- integration

def _gauss(n):
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


def _slopes(alpha):
    """Nodes over the GGX slope CDF u = tan²θm / (α² + tan²θm), as u = 1 − s² (smooth at grazing facets):
    cos θm, sin θm and the weights of ∫ D(m) (·) dωm = ∫ du ∫ dφ / (2π) (·) / cos θm."""
    s, w = _gauss(SPLIT_NODES)
    root = np.sqrt(s * s + alpha * alpha * (1.0 - s * s))
    return s / root, alpha * np.sqrt(1.0 - s * s) / root, 2.0 * root * w


def _azimuth_limit(x, a, b):
    """The azimuth φ ∈ [0, π] of m where i·m = a cos φ + b equals x (i·m > x for smaller φ)."""
    q = np.divide(x - b, a, out=np.where(x > b, np.inf, -np.inf) * np.ones_like(a), where=a > 0)
    return np.arccos(np.clip(q, -1.0, 1.0))


def reflection_nodes(mu, alpha, c_split=None):
    """Quadrature of the GGX reflection lobe for incidences ``mu`` (M,): i·h = c and weights w (M, Q) with
    Σ w F(c) = ∫ F(i·h) D G2 / (4 μ) dωo. Over each slope the azimuths that reflect above the horizon
    (i·m > μ / (2 cos θm)) are split in two Gauss segments at the facet cosine ``c_split`` (the critical one under
    TIR, where F has a square-root kink; else the middle)."""
    mu = np.maximum(np.asarray(mu, dtype=float), MIN_COS)[:, None, None]
    cos_m, sin_m, w_m = (v[None, :, None] for v in _slopes(alpha))
    a, b = np.sqrt(1.0 - mu * mu) * sin_m, mu * cos_m
    phi_max = _azimuth_limit(mu / (2.0 * cos_m), a, b)
    split = 0.5 * phi_max if c_split is None else np.minimum(_azimuth_limit(c_split[:, None, None], a, b), phi_max)
    t, w_t = _gauss(AZIMUTH_NODES)
    phi = np.concatenate([split * t, split + (phi_max - split) * t], axis=-1)
    w_phi = np.concatenate([split * w_t, (phi_max - split) * w_t], axis=-1)
    c = a * np.cos(phi) + b
    m = np.stack(np.broadcast_arrays(sin_m * np.cos(phi), sin_m * np.sin(phi), cos_m), axis=-1)
    wi = np.stack(np.broadcast_arrays(np.sqrt(1.0 - mu * mu), 0.0 * mu, mu), axis=-1)
    wo = 2.0 * c[..., None] * m - wi
    flat = (-1, 3)
    g2 = microfacet.g2(np.broadcast_to(wi, wo.shape).reshape(flat), wo.reshape(flat), alpha).reshape(c.shape)
    w = w_m * w_phi / np.pi * c * g2 / mu  # both signs of φ: 2 / (2π)
    return c.reshape(len(mu), -1), w.reshape(len(mu), -1)


def escape_fraction(mu, alpha, eta):
    """The share of the visible normals (Heitz's VNDF) for incidence ``mu`` (M,) on which a ray refracts into
    relative IOR ``eta`` < 1 (i·m > sqrt(1 − η²)); by the azimuth integral of i·m in closed form."""
    mu = np.maximum(np.asarray(mu, dtype=float), MIN_COS)[:, None]
    cos_m, sin_m, w_m = (v[None, :] for v in _slopes(alpha))
    a, b = np.sqrt(1.0 - mu * mu) * sin_m, mu * cos_m
    phi = _azimuth_limit(np.sqrt(np.maximum(1.0 - eta * eta, 0.0)), a, b)
    visible = a * np.sin(phi) + b * phi  # ∫_0^φ (a cos + b), over both signs of φ below
    g1 = 1.0 / (1.0 + microfacet.smith_lambda(np.concatenate([np.sqrt(1.0 - mu * mu), 0.0 * mu, mu], 1), alpha))
    return g1 / mu[:, 0] * np.sum(w_m * visible, axis=1) / np.pi


def lobe_rule(mu, alpha):
    """E(μ, α) and the two-node Gauss rule (c1, c2, w1) of the albedo-weighted distribution of i·h, for
    incidences ``mu`` (M,): w1 F(c1) + (1 − w1) F(c2) is its mean of F, exact for cubics in i·h (Golub-Welsch:
    the eigen-decomposition of the rule's Jacobi matrix, built from the distribution's first three moments)."""
    c, w = reflection_nodes(mu, alpha)
    albedo = w.sum(axis=1)
    p = w / albedo[:, None]
    mean = (p * c).sum(axis=1)
    var = (p * (c - mean[:, None]) ** 2).sum(axis=1)
    third = (p * (c - mean[:, None]) ** 3).sum(axis=1)
    second_mean = mean + np.divide(third, var, out=np.zeros_like(var), where=var > 1e-30)
    sd = np.sqrt(var)
    nodes, vectors = np.linalg.eigh(np.stack([np.stack([mean, sd], -1), np.stack([sd, second_mean], -1)], -2))
    return albedo, nodes[:, 0], nodes[:, 1], vectors[:, 0, 0] ** 2


def dielectric_fgd(mu_rare, alpha, eta):
    """FGD at the cosines ``mu_rare`` (M,) on the rarer side (module docstring) for one relative IOR ``eta``."""
    critical = None if eta >= 1.0 else np.full(len(mu_rare), np.sqrt(1.0 - eta * eta))
    c, w = reflection_nodes(denser_cos(mu_rare, eta), alpha, critical)
    return (w * microfacet.fresnel_dielectric(c, eta)).sum(axis=1)


def conductor_fgd(mu, alpha, eta, k):
    """The integrated FGD of a conductor of scalar n, k (to measure the Gauss rule against): (M,)."""
    c, w = reflection_nodes(mu, alpha)
    return (w * microfacet.fresnel_conductor(c.ravel(), [eta], [k])[:, 0].reshape(c.shape)).sum(axis=1)


# ------------------------------------------------------------------------------------------- build

def build() -> dict:
    """Every table (float32) by integration at the axes' nodes."""
    mus, alphas = cos_nodes(), alpha_nodes()
    etas, escape_etas = eta_nodes(ETA_NODES), eta_nodes(ESCAPE_NODES)
    out = {name: np.zeros(shape) for name, shape in (
        ("albedo", (COS_NODES, ALPHA_NODES)), ("fresnel_rule", (COS_NODES, ALPHA_NODES, 3)),
        ("fgd", (COS_NODES, ALPHA_NODES, ETA_NODES)), ("escape", (COS_NODES, ALPHA_NODES, ESCAPE_NODES)))}
    for j, alpha in enumerate(alphas):
        out["albedo"][:, j], *rule = lobe_rule(mus, alpha)
        out["fresnel_rule"][:, j] = np.stack(rule, axis=-1)
        for e, eta in enumerate(etas):
            out["fgd"][:, j, e] = dielectric_fgd(mus, alpha, eta)
        for e, eta in enumerate(escape_etas):
            out["escape"][:, j, e] = escape_fraction(denser_cos(mus, eta), alpha, eta) if eta < 1.0 else 1.0
    return {name: table.astype(np.float32) for name, table in out.items()}


def write(path, arrays: dict) -> None:
    """An .npz with a fixed timestamp per entry, so that the same arrays give the same bytes."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name in sorted(arrays):
            data = io.BytesIO()
            np.lib.format.write_array(data, np.ascontiguousarray(arrays[name]), allow_pickle=False)
            archive.writestr(zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0)), data.getvalue(),
                             compress_type=zipfile.ZIP_DEFLATED)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_bytes(buffer.getvalue())


# ------------------------------------------------------------------------------------------- lookup

class Cell(NamedTuple):
    """Where bilinear interpolation reads a (COS_NODES, ALPHA_NODES) table: the flat index of each point's lower
    corner and the weights of its four corners."""

    index: np.ndarray
    weights: tuple


def cell(mu, alpha) -> Cell:
    """The cells of cosines and roughnesses (broadcast together, clamped to the axes)."""
    x, y = np.broadcast_arrays(cos_coord(mu), alpha_coord(alpha))
    i, j = np.minimum(x.astype(np.intp), COS_NODES - 2), np.minimum(y.astype(np.intp), ALPHA_NODES - 2)
    fx, fy = x - i, y - j
    return Cell(i * ALPHA_NODES + j, ((1.0 - fx) * (1.0 - fy), (1.0 - fx) * fy, fx * (1.0 - fy), fx * fy))


def interpolate(table, at: Cell):
    """The (COS_NODES, ALPHA_NODES) ``table`` interpolated at ``at``."""
    flat, k = table.ravel(), at.index
    corners = (k, k + 1, k + ALPHA_NODES, k + ALPHA_NODES + 1)
    return sum(w * np.take(flat, c) for w, c in zip(at.weights, corners))


class Tables:
    """The tables in float64. Lookups take cosines and roughnesses (N,) (or scalars) and, for the IOR tables,
    constant relative IORs (one per channel): each is first interpolated along the IOR axis."""

    def __init__(self, arrays: dict):
        self.arrays = {name: np.asarray(table, dtype=float) for name, table in arrays.items()}
        self.rule = tuple(np.ascontiguousarray(self.arrays["fresnel_rule"][..., i]) for i in range(3))

    def albedo(self, mu, alpha):
        return interpolate(self.arrays["albedo"], cell(mu, alpha))

    def conductor_fgd(self, mu, alpha, eta, k):
        """E (w1 F(c1) + (1 − w1) F(c2)) for views ``mu`` (N,) and colours ``eta``, ``k`` (3,): (N, 3)."""
        at = cell(mu, alpha)
        c1, c2, w1 = (interpolate(table, at) for table in self.rule)
        f1, f2 = (microfacet.fresnel_conductor(c, eta, k) for c in (c1, c2))
        return interpolate(self.arrays["albedo"], at)[:, None] * (w1[:, None] * f1 + (1.0 - w1[:, None]) * f2)

    def _at_ior(self, name, eta: float):
        """The table ``name`` interpolated along its IOR axis at ``eta``: (COS_NODES, ALPHA_NODES)."""
        table = self.arrays[name]
        x = min(float(eta_coord(eta)), table.shape[2] - 1)
        i = min(int(x), table.shape[2] - 2)
        return (1.0 - (x - i)) * table[..., i] + (x - i) * table[..., i + 1]

    def _per_channel(self, name, mu, alpha, eta):
        columns = {e: interpolate(self._at_ior(name, e), cell(rarer_cos(mu, e), alpha)) for e in set(eta)}
        return np.stack([columns[e] for e in eta], axis=-1)

    def fgd(self, mu, alpha, eta):
        """Dielectric FGD (N, len(eta)) at incidences ``mu`` from the side above, relative IORs ``eta``."""
        return self._per_channel("fgd", mu, alpha, eta)

    def escape(self, mu, alpha, eta):
        """The escaping fraction (N, len(eta)) for light at ``mu`` leaving into relative IORs ``eta``."""
        inside = self._per_channel("escape", mu, alpha, [min(e, 1.0) for e in eta])
        return np.where(np.asarray(eta) < 1.0, inside, 1.0)


@lru_cache(maxsize=1)
def load() -> Tables:
    if not DATA.exists():
        raise FileNotFoundError(f"{DATA} is missing: reinstall Lamina or run python -m addon.reference."
                                f"aniso_stack_tables")
    with np.load(DATA) as data:
        return Tables({name: data[name] for name in data.files})


# ------------------------------------------------------------------------------------------- measurements

def random_points(rng, n, escape=False):
    """Uniform in the axes' coordinates: cosines (on the rarer side), roughnesses, relative IORs."""
    mu, alpha = rng.random(n) ** 2, (np.sqrt(MIN_ALPHA) + (1.0 - np.sqrt(MIN_ALPHA)) * rng.random(n)) ** 2
    return mu, alpha, eta_nodes_at(rng.random(n) * (HALF if escape else 2 * HALF))


def stack_points(rng, n):
    """What lookups meet on the mean paths of stacks seen from air: uniform view cosines and absolute IORs above
    and below an interface uniform in [1.0001, 3]; returns the cosines in the layer above and below, α, and the
    relative IOR below / above."""
    sin_o = np.sqrt(1.0 - rng.random(n) ** 2)
    above, below = rng.uniform(1.0001, 3.0, n), rng.uniform(1.0001, 3.0, n)
    alpha = (np.sqrt(MIN_ALPHA) + (1.0 - np.sqrt(MIN_ALPHA)) * rng.random(n)) ** 2
    cos_above, cos_below = (np.sqrt(1.0 - (sin_o / a) ** 2) for a in (above, below))
    return cos_above, cos_below, alpha, below / above


def _summary(name, error, mu=None):
    error = np.abs(error)
    far = "" if mu is None else f"; for cosines >= 0.05: max {error[mu >= 0.05].max():.2g}"
    print(f"{name}: max abs error {error.max():.2g}, RMS {np.sqrt(np.mean(error ** 2)):.2g}{far}")


def fgd_errors(tables: Tables, mu, alpha, eta):
    """Lookups against fresh integration at incidences ``mu`` from the side above."""
    fresh = [dielectric_fgd(rarer_cos(np.array([m]), e), a, e)[0] for m, a, e in zip(mu, alpha, eta)]
    return np.ravel([tables.fgd(m, a, [e]) for m, a, e in zip(mu, alpha, eta)]) - fresh


def escape_errors(tables: Tables, mu, alpha, eta):
    fresh = [escape_fraction(np.array([m]), a, e)[0] for m, a, e in zip(mu, alpha, eta)]
    return np.ravel([tables.escape(m, a, [e]) for m, a, e in zip(mu, alpha, eta)]) - fresh


def measure(tables: Tables, n: int = 2000, seed: int = 1) -> None:
    """Print the interpolation errors (over the axes, and at the stacks' mean paths), the conductor rule's error and
    the Fresnel-at-the-view shortcut's difference (module docstring)."""
    rng = np.random.default_rng(seed)
    mu, alpha, _ = random_points(rng, n)
    fresh = np.array([lobe_rule(np.array([m]), a)[0][0] for m, a in zip(mu, alpha)])
    _summary("albedo", tables.albedo(mu, alpha) - fresh, mu)
    mu_rare, alpha, eta = random_points(rng, n)
    _summary("fgd", fgd_errors(tables, denser_cos(mu_rare, eta), alpha, eta), mu_rare)
    mu_rare, alpha, eta = random_points(rng, n, escape=True)
    _summary("escape", escape_errors(tables, denser_cos(mu_rare, eta), alpha, eta), mu_rare)
    cos_above, cos_below, alpha, eta = stack_points(rng, n // 2)
    _summary("fgd on mean paths", fgd_errors(tables, cos_above, alpha, eta))
    leaving = eta > 1.0  # light going up from the denser layer below
    _summary("escape on mean paths", escape_errors(tables, cos_below[leaving], alpha[leaving], 1.0 / eta[leaving]))
    _measure_conductor(tables, n // 4, rng)
    _measure_view_fresnel(tables)


def _measure_conductor(tables: Tables, n: int, rng) -> None:
    mu, alpha = random_points(rng, n)[:2]
    eta, k = 10.0 ** rng.uniform(-2.0, 1.0, n), np.where(rng.random(n) < 0.2, 0.0, 10.0 ** rng.uniform(-1, 1.3, n))
    fresh = np.array([conductor_fgd(np.array([m]), a, e, kk)[0] for m, a, e, kk in zip(mu, alpha, eta, k)])
    rule = np.array([tables.conductor_fgd(np.array([m]), a, [e], [kk])[0, 0] for m, a, e, kk in zip(mu, alpha, eta, k)])
    metal = k >= 1.0
    _summary("conductor FGD by the Gauss rule", rule - fresh, mu)
    _summary("  (k >= 1)", (rule - fresh)[metal], mu[metal])


def _measure_view_fresnel(tables: Tables) -> None:
    """On a uniform grid of (cosine on the rarer side, α) at the IOR axis' nodes."""
    grid = np.linspace(0.0, 1.0, 65)[1:]
    mu_rare, alpha = (v.ravel() for v in np.meshgrid(grid, grid, indexing="ij"))
    moderate = (alpha <= 0.3) & (mu_rare >= 0.2)
    differences = {}
    for eta in eta_nodes(ETA_NODES):
        mu = denser_cos(mu_rare, eta)
        fgd, view = tables.fgd(mu, alpha, [eta])[:, 0], microfacet.fresnel_dielectric(mu, eta)
        for name, value in (("FGD", fgd), ("FGD / E", fgd / tables.albedo(mu, alpha))):
            differences.setdefault((name, eta >= 1.0), []).append(np.abs(value - view))
    for (name, above), d in differences.items():
        d = np.array(d)
        near = d[:, moderate]
        print(f"F at the view's cosine against {name}, eta {'>=' if above else '<'} 1: max {d.max():.2g}, RMS "
              f"{np.sqrt(np.mean(d ** 2)):.2g}; for alpha <= 0.3 and cosines >= 0.2: max {near.max():.2g}, "
              f"RMS {np.sqrt(np.mean(near ** 2)):.2g}")


def main() -> None:
    arrays = build()
    write(DATA, arrays)
    print(f"wrote {DATA} ({DATA.stat().st_size} bytes)")
    measure(Tables(arrays))


if __name__ == "__main__":
    main()
