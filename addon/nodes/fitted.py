"""The fitted mapping: a material's analytic closures with view-dependent scales, plus a few extra closures, fitted
to the reference BSDF (issue 14; bpy-free).

What a mapping's ``shade`` renders is a sum of closures whose weights depend on the view only. The fitted mapping
keeps those closures (their shapes: narrow peaks, tilted normals, anisotropy) and multiplies each closure's colour
by an RGB table over the view cosine; it may add up to ``MAX_EXTRAS`` closures from a small dictionary (Lambert,
translucency, GGX around the normal, GGX refraction around the view, Ashikhmin velvet for light between
grazing directions, Toon lobes for wide lobes that keep grazing light), each with an RGB weight table, beside the
material's closures or in place of one of them: the fitted mapping renders at most as many closures as the analytic
one (its render cost). Per tabulated view cosine the weights minimise the cosine-weighted error against the
reference over (ωi, ωo) (non-negative least squares), with the reference's own directional albedo matched (a
heavily weighted row). The forward model is ``closures_np``: the fit optimises what Cycles renders. Tables are
piecewise linear in √cos θo on ``KNOTS`` uniform knots (``view_cosines``; a Color Ramp in node groups, a constant
array in OSL: both exact). Where a closure's colour follows the view's elevation alone (constant inputs, no layer
oriented off the normal in it), its table carries colour × scale (``folded_colours``), so the shader no longer
computes that colour (docs/accuracy.md lists each preset's operations, analytic and fitted).

A driven input (``Driven``: fed by a texture or keyframes) adds an axis: the material is fitted at ``Driven.values``
(a few values across its range) with one set of closures, and the shader interpolates the tables linearly between
them at the input's value per shading point (per channel for a colour input: channel c of the tables follows
channel c of the input, exact where the material's channels are independent).

Quadrature over ωi: a Fibonacci sphere plus samples of each narrow closure's own microfacet distribution, combined
by the balance heuristic (multiple importance sampling), at ``AZIMUTHS`` view azimuths per knot: deterministic.
The fits a material is measured with (``nodes.choice.VARIANTS``) share it (``fit_variants``): the reference and the
closures are evaluated once, the normal equations once per weighting, and most small non-negative solves end at
their first, unconstrained solve (``nnls_gram``). Four fits of leaf took 12.3 s one by one and take 3.1 s so (the
same fits to 2e-12; one-off timing on this 2-core machine, idle).
"""
from __future__ import annotations

import contextlib
import ctypes
import functools
import glob
import hashlib
import json
import math
import os
from dataclasses import dataclass

import numpy as np

from . import closures_np

KNOTS = 16  # tabulated views (``view_cosines``)
MIN_KNOT_COS = 0.02  # views closer to grazing take the first knot's values
AZIMUTHS = 4  # view azimuths per knot (anisotropic materials; one suffices for isotropic ones)
UNIFORM = 1024  # Fibonacci-sphere directions per view
LOBE = 256  # samples per narrow closure per view
NARROW = 0.5  # closures of roughness below this get samples of their own
STRAIGHT_ALPHA = 0.25  # the width of the samples about the straight-through direction
MAX_EXTRAS = 2
ALBEDO_WEIGHT = 3.0  # the directional-albedo row's weight against the relative L2 residual
RIDGE = 1e-5  # pull towards the analytic mapping (scales 1, extras 0) where the data leave weights free
EXTRA_GAIN = 0.05  # an extra closure must lower the fit's error by this share to be kept,
MIN_GAIN = 0.005  # and by this much (relative RMSE)
FIXED = ("transparent",)  # exact closures (a Dirac): never rescaled
SHAPELESS = ("diffuse", "translucent")  # closures without a shape: the dictionary's are not added beside them


def view_cosines() -> np.ndarray:
    """The view cosine of each knot: uniform in √cos θo from √``MIN_KNOT_COS`` to 1 (dense at grazing views, where
    the layers change fastest)."""
    return np.linspace(math.sqrt(MIN_KNOT_COS), 1.0, KNOTS) ** 2


def table_coordinate(b):
    """The tables' coordinate on backend ``b``: 0 at ``MIN_KNOT_COS`` (and below), 1 at normal view, uniform in
    √cos θo (``view_cosines``)."""
    root = math.sqrt(MIN_KNOT_COS)
    return (b.sqrt(b.cos_view()) - root) * (1.0 / (1.0 - root))


# ------------------------------------------------------------------------------ the extra closures

def extra_dictionary(toons: bool = False) -> list[tuple[str, dict]]:
    """(kind, parameters) of the closures the fit may add, each with a white colour: those whose Cycles rendering
    ``closures_np`` predicts under suns and in the furnace (tests/blender), with ``TOONS`` if ``toons``. Refraction
    around the normal is not among them: under a uniform sky Cycles renders it darker at grazing views than its
    evaluation integrates to (seen in a one-off render, α = 1, IOR 1.5; not yet a test), so its prediction would be
    off there. Nor is Ashikhmin–Shirley glossy, though it keeps grazing light and lowered the thin coats' fitted
    errors (a throwaway fit: amber_lacquer sphere 9.1% → 6.1%): Cycles renders more than its evaluation at grazing
    views under environment light (tests/blender/test_cycles_facts.py)."""
    up = (0.0, 0.0, 1.0)
    out = [("diffuse", {}), ("translucent", {})]
    out += [("ggx", {"alpha": a, "normal": up}) for a in (0.1, 0.15, 0.2, 0.3, 0.45, 0.6, 0.8, 1.0)]
    out += [("ggx_refraction", {"alpha": a, "ior": 10.0, "normal": "view"}) for a in (0.1, 0.2, 0.3, 0.5, 0.7, 1.0)]
    out += [("velvet", {"sigma": s}) for s in (0.2, 0.3, 0.5)]  # wider ones rob the sun-lit views (leaf)
    return out + list(TOONS) if toons else out


# Toon lobes keep light at grazing incidence, which every microfacet closure's masking takes away: a tent about the
# mirror direction 90° wide and a lobe flat over the hemisphere (f cos θi constant) stand in for the wide ENDF lobes
# of a rough bottom under a smooth top (smooth_over_rough, docs/accuracy.md). Elsewhere they can lower the fit's own
# error while raising the comparison scenes' (leaf): a dictionary with them is one of the fits ``nodes.choice`` tries.
TOONS = (("glossy_toon", {"size": 0.0, "smooth": 1.0}), ("diffuse_toon", {"size": 1.0, "smooth": 0.0}))


def _extra_kwargs(kind: str, kw: dict, wo: np.ndarray) -> dict:
    """An extra closure's parameters as ``closures_np.EVAL[kind]`` takes them for the views ``wo``."""
    n = len(wo)
    out = dict(kw)
    if "normal" in kw:
        out["normal"] = wo if kw["normal"] == "view" else np.broadcast_to(np.asarray(kw["normal"], dtype=float), (n, 3))
    if kind == "ggx":  # isotropic
        alpha = out.pop("alpha")
        out.update(alpha_x=alpha, alpha_y=alpha, tangent=np.broadcast_to([1.0, 0.0, 0.0], (n, 3)))
    return out


# ------------------------------------------------------------------------------ quadrature

def fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _frame(normal, tangent):
    n = normal / np.linalg.norm(normal, axis=1, keepdims=True)
    t = tangent - np.einsum("ij,ij->i", tangent, n)[:, None] * n
    length = np.linalg.norm(t, axis=1, keepdims=True)
    fallback = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t = np.where(length > 1e-9, t / np.maximum(length, 1e-12), fallback - np.einsum(
        "ij,ij->i", fallback, n)[:, None] * n)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return t, np.cross(n, t), n


@dataclass(frozen=True)
class Lobe:
    """A narrow lobe to importance-sample: slopes of GGX (or Beckmann) (αx, αy) about ``normal``, the sampled
    microfacet normal reflecting ωo, or (``through``) itself the direction (a cone about ``normal``)."""
    normal: np.ndarray  # (3,)
    tangent: np.ndarray  # (3,)
    alpha_x: float
    alpha_y: float
    beckmann: bool
    through: bool = False

    def _local(self, v):
        t, b, n = _frame(self.normal[None], self.tangent[None])
        return np.stack([v @ t[0], v @ b[0], v @ n[0]], axis=1)

    def sample(self, wo: np.ndarray, u: np.ndarray) -> np.ndarray:
        t, b, n = _frame(self.normal[None], self.tangent[None])
        radius = np.sqrt(-np.log1p(-u[:, 0])) if self.beckmann else np.sqrt(u[:, 0] / (1.0 - u[:, 0]))
        phi = 2.0 * math.pi * u[:, 1]
        sx, sy = self.alpha_x * radius * np.cos(phi), self.alpha_y * radius * np.sin(phi)
        h = -sx[:, None] * t - sy[:, None] * b + n
        h /= np.linalg.norm(h, axis=1, keepdims=True)
        return h if self.through else 2.0 * (h @ wo)[:, None] * h - wo

    def pdf(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        h = wi if self.through else wi + wo
        h = h / np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-300)
        hl = self._local(h)
        ok = hl[:, 2] > 1e-9
        hz = np.where(ok, hl[:, 2], 1.0)
        if self.beckmann:
            t2 = ((hl[:, 0] / self.alpha_x) ** 2 + (hl[:, 1] / self.alpha_y) ** 2) / (hz * hz)
            d = np.exp(-t2) / (math.pi * self.alpha_x * self.alpha_y * hz ** 4)
        else:
            d = closures_np.ggx_d(np.where(ok[:, None], hl, [[0.0, 0.0, 1.0]]), self.alpha_x, self.alpha_y)
        jacobian = 1.0 if self.through else 1.0 / np.maximum(4.0 * np.abs(np.einsum("ij,ij->i", h, wo)), 1e-300)
        return np.where(ok, d * hz * jacobian, 0.0)


def narrow_lobes(closures, view: int) -> list[Lobe]:
    """The narrow reflection lobes among a view's recorded closures (``NumpyBackend.closures``), deduplicated."""
    out = {}
    for kind, _, kw in closures:
        if kind in ("ggx", "ggx_conductor"):
            ax, ay = float(np.ravel(kw["alpha_x"])[view]), float(np.ravel(kw["alpha_y"])[view])
            normal = np.asarray(kw.get("normal", (0.0, 0.0, 1.0)), dtype=float)
            normal = normal[view] if normal.ndim == 2 else normal
            tangent = np.asarray(kw["tangent"], dtype=float)
            tangent = tangent[view] if tangent.ndim == 2 else tangent
            beckmann = False
        elif kind in ("beckmann", "conductor", "dielectric"):
            ax = ay = float(np.ravel(kw["alpha"])[view] if np.ndim(kw["alpha"]) else kw["alpha"])
            normal = np.asarray(kw.get("normal", (0.0, 0.0, 1.0)), dtype=float)
            normal = normal[view] if normal.ndim == 2 else normal
            tangent, beckmann = np.array([1.0, 0.0, 0.0]), kind == "beckmann"
        else:
            continue
        ax, ay = max(ax, 1e-4), max(ay, 1e-4)
        if min(ax, ay) < NARROW:
            key = (tuple(np.round(normal, 6)), tuple(np.round(tangent, 6)), round(ax, 6), round(ay, 6), beckmann)
            out[key] = Lobe(normal, tangent, ax, ay, beckmann)
    return list(out.values())


def quadrature(wo: np.ndarray, lobes: list[Lobe], seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Directions ωi and weights (∫ g dωi ≈ Σ w g) for one view: the Fibonacci sphere, each lobe's samples and a
    cone about the straight-through direction −ωo (transmission peaks), balance heuristic."""
    rng = np.random.default_rng(seed)
    lobes = lobes + [Lobe(-wo, np.array([1.0, 0.0, 0.0]), STRAIGHT_ALPHA, STRAIGHT_ALPHA, False, through=True)]
    parts = [fibonacci_sphere(UNIFORM)]
    for lobe in lobes:
        parts.append(lobe.sample(wo, rng.random((LOBE, 2))))
    wi = np.concatenate(parts)
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo_n = np.broadcast_to(wo, wi.shape)
    density = np.full(len(wi), UNIFORM / (4.0 * math.pi))
    for lobe in lobes:
        density = density + LOBE * lobe.pdf(wi, wo_n)
    return wi, 1.0 / density


# ------------------------------------------------------------------------------ non-negative least squares

def nnls_gram(gram: np.ndarray, rhs: np.ndarray, tol: float = 1e-12) -> np.ndarray:
    """argmin ½ xᵀ G x − hᵀ x over x ≥ 0 (Lawson–Hanson active set on the normal equations; G positive
    definite)."""
    n = len(rhs)
    x = np.linalg.solve(gram, rhs)
    if (x > tol * np.abs(x).max()).all():  # the unconstrained minimum is positive: the answer, in one solve
        return x
    x = np.zeros(n)
    passive = np.zeros(n, dtype=bool)
    for _ in range(3 * n + 10):
        grad = rhs - gram @ x
        free = ~passive & (grad > tol * max(1.0, np.abs(rhs).max()))
        if not free.any():
            break
        passive[np.argmax(np.where(free, grad, -np.inf))] = True
        while True:
            z = np.zeros(n)
            z[passive] = np.linalg.solve(gram[np.ix_(passive, passive)], rhs[passive])
            if (z[passive] > 0.0).all():
                x = z
                break
            blocking = passive & (z <= 0.0)
            step = np.min(x[blocking] / np.maximum(x[blocking] - z[blocking], 1e-300))
            x = x + step * (z - x)
            passive &= x > tol
            x[~passive] = 0.0
    return x


# ------------------------------------------------------------------------------ one BLAS thread

OPENBLAS_SUFFIXES = ("64_", "_64_", "")  # numpy's own OpenBLAS builds name their symbols with one of these


@functools.lru_cache(maxsize=1)
def openblas_threads():
    """(get, set) of the thread count of the OpenBLAS bundled with numpy (``numpy.libs``, ``numpy/.dylibs``), or
    None where numpy uses another BLAS."""
    root = os.path.dirname(np.__file__)
    for path in sorted(glob.glob(os.path.join(root + ".libs", "*openblas*")) +
                       glob.glob(os.path.join(root, ".dylibs", "*openblas*"))):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for suffix in OPENBLAS_SUFFIXES:
            get = getattr(lib, f"openblas_get_num_threads{suffix}", None)
            put = getattr(lib, f"openblas_set_num_threads{suffix}", None)
            if get is not None and put is not None:
                return get, put
    return None


@contextlib.contextmanager
def one_blas_thread():
    """OpenBLAS on one thread inside (restored after): the fit solves thousands of systems of a dozen unknowns, and
    a threaded solve waits for a busy core (a 12 x 12 numpy.linalg.solve: 12 µs idle, 144 µs beside a busy core,
    8 µs on one thread; measured once on the 2-core development machine). The Makefile gives make's runs one thread
    the same way. Nothing changes where numpy uses another BLAS."""
    threads = openblas_threads()
    if threads is None:
        yield
        return
    get, put = threads
    before = get()
    put(1)
    try:
        yield
    finally:
        put(before)


# ------------------------------------------------------------------------------ the fit

@dataclass(frozen=True)
class Driven:
    """A shader input fed by a texture: the fit's tables are tabulated at ``values`` (uniform, ascending) of it."""
    socket: str  # the shader input, e.g. "L2 Albedo"
    kind: str  # "float" or "color" (a colour input is tabulated at greys)
    values: tuple  # the input's values the tables hold, uniform from the texture's least to its greatest

    def to_json(self) -> list:
        return [self.socket, self.kind, list(self.values)]

    @classmethod
    def from_json(cls, data) -> "Driven":
        socket, kind, values = data
        return cls(socket, kind, tuple(float(v) for v in values))

    def value(self, j: int):
        """What the input holds at the j-th tabulated value (a grey for a colour input)."""
        return self.values[j] if self.kind == "float" else (self.values[j],) * 3

    def weights(self, b) -> list:
        """Per tabulated value, the linear interpolation weight of the input's value on backend ``b`` (a colour of
        weights for a colour input); values outside the range take the nearest end's tables."""
        lo, hi, last = self.values[0], self.values[-1], len(self.values) - 1
        if last == 0:
            return [1.0]
        x = b.minimum(b.maximum((b.input(self.socket, self.kind) - lo) * (last / (hi - lo)), 0.0), float(last))
        return [b.maximum(b.minimum(x - (j - 1), (j + 1) - x), 0.0) for j in range(last + 1)]


@dataclass(frozen=True)
class Fit:
    """A material's fitted mapping: ``scales`` (J, KNOTS, 3) of its analytic closures (in recording order, the
    ``FIXED`` ones skipped), ``extras`` (kind, parameters) with their weights (E, KNOTS, 3), and the relative RMSE
    of both mappings in the fit's own quadrature. With ``driven``, the tables have an axis of its values:
    (J, G, KNOTS, 3) and (E, G, KNOTS, 3), and the errors are the means over them."""
    scales: np.ndarray
    extras: tuple
    extra_weights: np.ndarray
    error_analytic: float
    error_fitted: float
    groups: tuple = ()  # the atom of each rescaled closure, in recording order (``atom_groups``)
    driven: Driven | None = None

    LABEL = "fitted"  # in the names of the shaders that carry the tables

    def to_json(self) -> dict:
        """Lists (a material keeps its fit: what it renders can be predicted anywhere); ``from_arrays`` reads
        them back."""
        return {k: (v.tolist() if isinstance(v, np.ndarray) and v.ndim else
                    (str(v) if isinstance(v, np.ndarray) else v)) for k, v in self.to_arrays().items()}

    def to_arrays(self) -> dict:
        """Plain arrays (``np.savez``); ``from_arrays`` reads them back."""
        return {"scales": self.scales, "extra_weights": self.extra_weights,
                "extras": np.array(json.dumps(self.extras)), "groups": np.array(self.groups, dtype=int),
                "errors": np.array([self.error_analytic, self.error_fitted]),
                "driven": np.array(json.dumps(self.driven and self.driven.to_json()))}

    @classmethod
    def from_arrays(cls, a) -> "Fit":
        extras = tuple((kind, {k: tuple(v) if isinstance(v, list) else v for k, v in kw.items()})
                       for kind, kw in json.loads(str(a["extras"])))
        driven = json.loads(str(a["driven"])) if "driven" in a else None
        return cls(np.asarray(a["scales"]), extras, np.asarray(a["extra_weights"]), *map(float, a["errors"]),
                   tuple(int(g) for g in a["groups"]), driven and Driven.from_json(driven))

    def digest(self) -> str:
        """A short content hash (names the shader that carries the tables)."""
        h = hashlib.md5(np.round(self.scales, 6).tobytes() + np.round(self.extra_weights, 6).tobytes())
        driven = self.driven and self.driven.to_json()
        h.update(json.dumps([self.extras, self.groups, driven], sort_keys=True).encode())
        return h.hexdigest()[:8]


def _views(mu: float) -> np.ndarray:
    phi = 2.0 * math.pi * (np.arange(AZIMUTHS) + 0.25) / AZIMUTHS
    s = math.sqrt(max(1.0 - mu * mu, 0.0))
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.full(AZIMUTHS, mu)], axis=1)


def _fitted_closures(recorded):
    return [(kind, color, kw) for kind, color, kw in recorded if kind not in FIXED]


def _signature(kind: str, kw: dict) -> bytes:
    parts = [kind.encode()]
    for key in sorted(kw):
        value = kw[key]
        parts.append(key.encode() + (np.round(np.asarray(value, dtype=float), 9).tobytes() if value is not None
                                     else b"none"))
    return b"|".join(parts)


def atom_groups(backend_of) -> tuple[int, ...]:
    """The atom of each closure the fit rescales (``FIXED`` ones skipped), in recording order: closures of the same
    kind with the same parameters at every fitted view share one (only their sum can be told apart; the fitted
    mapping renders them as one closure)."""
    views = np.concatenate([_views(mu) for mu in view_cosines()])
    closures = _fitted_closures(backend_of(views).closures)
    groups, seen = [], {}
    for kind, _, kw in closures:
        groups.append(seen.setdefault(_signature(kind, kw), len(seen)))
    return tuple(groups)


def _atoms(recorded, groups, extras, wi, wo) -> np.ndarray:
    """(S, A + E, 3): each atom's value (its closures' colours included) for the directions ``wi`` (one view)."""
    n_atoms = 1 + max(groups, default=-1)
    out = np.zeros((len(wi), n_atoms + len(extras), 3))
    for g, (kind, color, kw) in zip(groups, _fitted_closures(recorded)):
        out[:, g] += np.broadcast_to(color, (len(wi), 3)) * closures_np.EVAL[kind](wi, wo, **kw)
    for e, (kind, kw) in enumerate(extras):
        out[:, n_atoms + e] = closures_np.EVAL[kind](wi, wo, **_extra_kwargs(kind, kw, wo))
    return out


@dataclass
class _Normal:
    """One knot and channel's least-squares problem: AᵀA, Aᵀt, tᵀt of the cosine-weighted residual, and the
    albedo rows (atoms' albedos per view, target albedos)."""
    ata: np.ndarray
    att: np.ndarray
    tt: float
    albedo_atoms: np.ndarray  # (V, J + E)
    albedo_target: np.ndarray  # (V,)


@dataclass
class _View:
    """One fitted view's quadrature: the atoms' values (S, J + E, 3) and the reference's (S, 3) at the directions
    ωi, their weights times |cos θi|, the side of each ωi, and the reference's mean level (``fit``'s residual
    weighting). Every weighting and dictionary of a material is fitted on the same ones (``fit_variants``)."""
    atoms: np.ndarray
    reference: np.ndarray
    weight: np.ndarray  # the quadrature weight
    cos_i: np.ndarray  # |cos θi|
    above: np.ndarray  # ωi above the surface (reflection), else below (transmission)
    level: float


def _knot_views(backend_of, ref_eval, ref_albedo, mu, groups, extras) -> list[_View]:
    """The views at view cosine ``mu`` (``AZIMUTHS`` azimuths)."""
    out = []
    for v, wo in enumerate(_views(mu)):
        one = backend_of(wo[None])
        wi, w = quadrature(wo, narrow_lobes(one.closures, 0), seed=v)
        wo_s = np.repeat(wo[None], len(wi), axis=0)
        recorded = backend_of(wo_s).closures
        level = max(float(np.mean(ref_albedo(wo[None])[0])) / math.pi, 1e-6)
        out.append(_View(_atoms(recorded, groups, extras, wi, wo_s), ref_eval(wi, wo_s), w, np.abs(wi[:, 2]),
                         wi[:, 2] > 0.0, level))
    return out


def _knot_systems(views: list[_View], damping: float) -> list[_Normal]:
    """The three channels' problems at one knot (its ``views``) for the residual weighting ``damping``."""
    rows, targets, albedo_atoms, albedo_targets = [], [], [], []
    for view in views:
        a, f, w, cos_i = view.atoms, view.reference, view.weight, view.cos_i
        r = np.sqrt(w) * cos_i / (view.level + f.mean(axis=1) * cos_i) ** damping
        rows.append(a * r[:, None, None])
        targets.append(f * r[:, None])
        for side in (view.above, ~view.above & (cos_i > 0.0)):  # reflection and transmission albedo, each matched
            albedo_atoms.append(np.einsum("s,sjc->jc", w * cos_i * side, a))
            albedo_targets.append(np.einsum("s,sc->c", w * cos_i * side, f))
    # channel-major copies: numpy's matrix products use BLAS only on contiguous rows (a channel's slice of the
    # (rows, atoms, 3) array is not; its product took 16 times as long)
    a = np.ascontiguousarray(np.moveaxis(np.concatenate(rows), 2, 0))
    t = np.ascontiguousarray(np.concatenate(targets).T)
    alb_a, alb_t = np.stack(albedo_atoms), np.stack(albedo_targets)
    return [_Normal(a[c].T @ a[c], a[c].T @ t[c], float(t[c] @ t[c]), alb_a[:, :, c], np.maximum(alb_t[:, c], 0.0))
            for c in range(3)]


def _channel_system(s: _Normal, idx: np.ndarray, scale: float):
    """One channel's normalised normal equations (G, h) over the atoms ``idx``: the residual over ``scale`` and
    the albedo rows."""
    albedo = max(float(s.albedo_target.max()), 1e-3)
    rows = s.albedo_atoms[:, idx] * (ALBEDO_WEIGHT / albedo)
    gram = s.ata[np.ix_(idx, idx)] / scale + rows.T @ rows
    rhs = s.att[idx] / scale + rows.T @ (s.albedo_target * (ALBEDO_WEIGHT / albedo))
    return gram, rhs


@dataclass
class _Stacked:
    """One knot's problem over the weights of every atom at once, ridge towards the analytic mapping included: a
    ``grey`` atom has one weight for all channels (a closure whose node takes a grey weight), the others one per
    channel; ``_solve_knot`` takes the rows and columns of the atoms it uses."""
    gram: np.ndarray
    rhs: np.ndarray
    atom: np.ndarray  # (W,) the atom of each weight
    channels: np.ndarray  # (3, W) the channels each weight scales


def _stacked(knot: list[_Normal], grey: np.ndarray, n_analytic: int) -> _Stacked:
    every = np.arange(len(grey))
    # the residual relative to the reference's energy; a black reference: to the closures' own
    scale = max(max(s.tt for s in knot), 1e-9 * max(float(np.diag(s.ata).max()) for s in knot), 1e-300)
    atom = np.concatenate([[j] if grey[j] else [j, j, j] for j in every]).astype(int)
    channels = np.concatenate([np.ones((3, 1), dtype=bool) if grey[j] else np.eye(3, dtype=bool) for j in every],
                              axis=1)
    gram = RIDGE * np.eye(len(atom))
    rhs = RIDGE * (atom < n_analytic)
    for c, s in enumerate(knot):
        g, h = _channel_system(s, every, scale)
        gram += np.outer(channels[c], channels[c]) * g[np.ix_(atom, atom)]
        rhs += channels[c] * h[atom]
    return _Stacked(gram, rhs, atom, channels)


def _solve_knot(knot: _Stacked, use: np.ndarray) -> np.ndarray:
    """The non-negative weights (3, J + E) of the atoms in ``use`` at one knot."""
    chosen = np.flatnonzero(use[knot.atom])
    v = nnls_gram(knot.gram[np.ix_(chosen, chosen)], knot.rhs[chosen])
    x = np.zeros((3, len(use)))
    channel, column = np.nonzero(knot.channels[:, chosen])
    x[channel, knot.atom[chosen][column]] = v[column]
    return x


def _residual(s: _Normal, x: np.ndarray) -> float:
    return max(float(x @ s.ata @ x - 2.0 * x @ s.att + s.tt), 0.0)


def _error(systems, weights) -> float:
    """Relative RMSE over all knots and channels (the fit's quadrature and weighting)."""
    num = sum(_residual(s, x[c]) for knot, x in zip(systems, weights) for c, s in enumerate(knot))
    den = sum(s.tt for knot in systems for s in knot)
    return math.sqrt(num / max(den, 1e-300))


def _solve_all(stacked, use) -> list[np.ndarray]:
    return [_solve_knot(knot, use) for knot in stacked]


def _grey(kind: str, kw: dict, form: str) -> bool:
    """Whether the node group takes this closure's weight as grey (``node_backend``: the conductor, a Beckmann
    reflection with a Fresnel)."""
    return form == "nodes" and (kind == "conductor" or (kind == "beckmann" and kw.get("eta") is not None))


def fit(backend_of, ref_eval, ref_albedo, form: str, damping: float = 1.0, toons: bool = False, groups=None,
        extras=None, atoms=None) -> Fit:
    """Fit the mapping whose view-only closures ``backend_of(wo)`` records (a ``NumpyBackend`` after ``shade``)
    against the reference ``ref_eval(wi, wo)`` (N, 3) and directional albedo ``ref_albedo(wo)`` (N, 3): up to
    ``MAX_EXTRAS`` extra closures chosen greedily (``_chosen``; from ``extra_dictionary(toons)``), each kept only if
    it lowers the error by ``EXTRA_GAIN``, within the analytic mapping's closure count. The residual at each
    direction is divided by (the reference's mean level + its value)^``damping``: 1 weighs relative errors (a peak
    counts no more than the dim rest), 0 absolute ones. Given ``groups`` (the atoms), ``extras`` (the extra closures,
    all used) and ``atoms`` (which atoms render; all by default), the fit keeps that structure (``fit_driven``)."""
    return fit_variants(backend_of, ref_eval, ref_albedo, form, [(damping, toons)], groups, extras, atoms)[0]


@one_blas_thread()
def fit_variants(backend_of, ref_eval, ref_albedo, form: str, variants, groups=None, extras=None,
                 atoms=None, spare: int = 0) -> list[Fit]:
    """``fit`` for each (damping, toons) of ``variants``, in that order, on one quadrature: the reference, the
    analytic closures and the whole dictionary are evaluated once (``_knot_views``), the normal equations once per
    weighting, and a variant without the Toon lobes leaves their columns out of its greedy choice. The same fits as
    one ``fit`` each, at a fraction of the time. ``spare``: closures the fit may render beyond the analytic
    mapping's count, and as many more extra closures (a measurement of what a larger render cost would buy,
    ``bench.fit_ceiling``; materials are fitted with none)."""
    analytic = backend_of(np.array([[0.0, 0.0, 1.0]]))
    closures = _fitted_closures(analytic.closures)
    groups = atom_groups(backend_of) if groups is None else tuple(groups)
    present = {kind for kind, _, _ in closures}
    fixed = extras is not None
    if not fixed:
        with_toons = any(toons for _, toons in variants)
        extras = [(kind, kw) for kind, kw in extra_dictionary(with_toons)
                  if not (kind in SHAPELESS and kind in present)]
    n_analytic = 1 + max(groups, default=-1)
    grey = np.zeros(n_analytic + len(extras), dtype=bool)
    for g, (kind, _, kw) in zip(groups, closures):
        grey[g] = _grey(kind, kw, form)
    views = [_knot_views(backend_of, ref_eval, ref_albedo, mu, groups, extras) for mu in view_cosines()]
    toon = np.array([(kind, kw) in TOONS for kind, kw in extras], dtype=bool)
    analytic_use = np.arange(n_analytic + len(extras)) < n_analytic
    budget = analytic.closure_count() - len({kind for kind, _, _ in analytic.closures if kind in FIXED}) + spare
    systems_of, fits = {}, []
    for damping, toons in variants:
        if damping not in systems_of:
            systems = [_knot_systems(knot, damping) for knot in views]
            systems_of[damping] = systems, [_stacked(knot, grey, n_analytic) for knot in systems]
        systems, stacked = systems_of[damping]
        error_analytic = _error(systems, [np.tile(analytic_use.astype(float), (3, 1))] * len(systems))
        if fixed:
            use = np.concatenate([np.ones(n_analytic, dtype=bool) if atoms is None else np.asarray(atoms, dtype=bool),
                                  np.ones(len(extras), dtype=bool)])
            best = _solve_all(stacked, use)
            error = _error(systems, best)
        else:
            # with spare closures, the greedy path may end above the shipped budget's: a larger budget keeps both
            use, best, error = min((_chosen(systems, stacked, analytic_use, n_analytic, budget - s, toons or ~toon,
                                            MAX_EXTRAS + spare - s) for s in sorted({spare, 0})), key=lambda c: c[2])
        x = np.transpose(np.stack(best), (2, 0, 1))  # (A + E, K, 3)
        chosen = np.flatnonzero(use[n_analytic:])
        fits.append(Fit(x[:n_analytic], tuple(extras[e] for e in chosen), x[n_analytic + chosen], error_analytic,
                        error, groups))
    return fits


def _rendered(use: np.ndarray, weights) -> np.ndarray:
    """The atoms of ``use`` that the solved ``weights`` keep somewhere (one the fit zeroes at every knot is not
    rendered: ``ScaledBackend.flush``, ``shade``)."""
    return use & (np.max([x.max(axis=0) for x in weights], axis=0) > 0.0)


def _chosen(systems, stacked, use, n_analytic: int, budget: int, allowed=True, moves: int = MAX_EXTRAS):
    """(use, weights, error): greedy moves from the analytic atoms, each the best of adding one extra closure
    (of those ``allowed``, a mask over the extras) while the rendered closures stay within ``budget``, or putting
    one in place of a rendered atom; a move is kept only if it lowers the error by ``EXTRA_GAIN`` and ``MIN_GAIN``,
    at most ``moves`` of them."""
    best = _solve_all(stacked, use)
    use = _rendered(use, best)
    error = _error(systems, best)
    for _ in range(moves):
        trials = []
        for e in np.flatnonzero(~use[n_analytic:] & allowed) + n_analytic:
            added = use.copy()
            added[e] = True
            dropped = [None] if added.sum() <= budget else np.flatnonzero(use)
            for d in dropped:
                trial = added.copy()
                if d is not None:
                    trial[d] = False
                weights = _solve_all(stacked, trial)
                trials.append((_error(systems, weights), _rendered(trial, weights), weights))
        if not trials:
            break
        new_error, trial, weights = min(trials, key=lambda t: t[0])
        if new_error > (1.0 - EXTRA_GAIN) * error or error - new_error < MIN_GAIN:
            break
        use, error, best = trial, new_error, weights
    return use, best, error


def common_groups(backends_of) -> tuple[int, ...]:
    """The atoms of closures that are alike at every tabulated value (``atom_groups`` of each): closures merged at
    one value but not at another stay apart."""
    per_value = [atom_groups(b) for b in backends_of]
    if len({len(g) for g in per_value}) > 1:
        raise ValueError("the material's closures change with the driven input: it cannot be tabulated over it")
    labels: dict = {}
    return tuple(labels.setdefault(key, len(labels)) for key in zip(*per_value))


def fit_driven(problems, driven: Driven, form: str, damping: float = 1.0, toons: bool = False, progress=None) -> Fit:
    """The fit of a texture-driven material: ``problems[j]`` = (backend_of, ref_eval, ref_albedo) with the input at
    ``driven.values[j]``. The middle value chooses the extra closures and the atoms that render; every value is
    fitted with them and the ``common_groups``. ``progress(fraction)`` after each value."""
    groups = common_groups([backend_of for backend_of, _, _ in problems])
    middle = len(problems) // 2
    order = [middle] + [j for j in range(len(problems)) if j != middle]
    fits = {}
    for done, j in enumerate(order):
        structure = {} if j == middle else {"extras": list(fits[middle].extras),
                                            "atoms": fits[middle].scales.max(axis=(1, 2)) > 0.0}
        fits[j] = fit(*problems[j], form, damping, toons, groups, **structure)
        if progress is not None:
            progress((done + 1) / len(order))
    ordered = [fits[j] for j in range(len(problems))]
    errors = [float(np.mean([getattr(f, name) for f in ordered])) for name in ("error_analytic", "error_fitted")]
    return Fit(np.stack([f.scales for f in ordered], axis=1), ordered[middle].extras,
               np.stack([f.extra_weights for f in ordered], axis=1), *errors, groups, driven)


# ------------------------------------------------------------------------------ shading

CLOSURES = ("glossy", "diffuse", "translucent", "conductor", "dielectric", "beckmann", "refraction")


class ScaledBackend:
    """A backend that passes everything to ``b`` but gathers the closures by atom (``Fit.groups``): one closure
    per atom, its members' colours summed, times the atom's fitted table; ``flush`` emits them."""

    def __init__(self, b, fit: Fit, table):
        self._b = b
        self._fit = fit
        self.table = table  # ``tables``
        self._next = 0
        self._atoms: dict[int, list] = {}  # atom -> [method, summed colour, args, kw]

    def __getattr__(self, name):
        attr = getattr(self._b, name)
        if name not in CLOSURES:
            return attr

        def gathered(color, *args, **kw):
            g = self._fit.groups[self._next]
            self._next += 1
            if g in self._atoms:
                self._atoms[g][1] = self._atoms[g][1] + color
            else:
                self._atoms[g] = [attr, color, args, kw]

        return gathered

    def flush(self, folded: dict | None = None) -> None:
        """Emit one closure per atom; an atom the fit set to zero at every view is left out. An atom in ``folded``
        ({atom: its colour (KNOTS, 3) at the knots' views}, ``folded_colours``) takes the table of that colour times
        its scale alone: its own colour math no longer feeds a closure."""
        for g, (method, color, args, kw) in self._atoms.items():
            scale = self._fit.scales[g]
            if scale.max() <= 0.0:
                continue
            if folded and g in folded:
                method(self.table(folded[g] * scale), *args, **kw)
            else:
                method(color * self.table(scale), *args, **kw)


FOLD_AZIMUTHS = (0.0, 1.3, 2.9)  # view azimuths (radians) at which an atom's colour must agree to be folded


def folded_colours(mapping, p, fit: Fit, knot_backend) -> dict:
    """{atom: colour (KNOTS, 3)} of the atoms whose summed colour is a function of the view's elevation alone: the
    same at every one of ``FOLD_AZIMUTHS`` at each knot's view (``knot_backend(wo)``: a ``NumpyBackend`` of ``p`` at
    the views ``wo``). Tables are piecewise linear between the knots either way; folding the colour in makes the
    product colour × scale piecewise linear instead of the scale alone [named: fitted-folded-colour], and leaves the
    colour's arithmetic out of the shader (constant inputs only: a driven fit keeps its colours)."""
    if fit.driven is not None:
        return {}
    mu = view_cosines()
    sine = np.sqrt(1.0 - mu * mu)
    seen = []
    for phi in FOLD_AZIMUTHS:
        b = knot_backend(np.stack([sine * math.cos(phi), sine * math.sin(phi), mu], axis=1))
        gathered = ScaledBackend(b, fit, None)
        mapping.shade(gathered, p)
        seen.append({g: np.broadcast_to(np.asarray(color, dtype=np.float64), (len(mu), 3))
                     for g, (_, color, _, _) in gathered._atoms.items()})
    return {g: colour for g, colour in seen[0].items()
            if all(np.allclose(other[g], colour, rtol=1e-9, atol=1e-12) for other in seen[1:])}


def tables(b, fit: Fit):
    """A function of one closure's table (K, 3), or (G, K, 3) when ``fit.driven``, returning its colour on backend
    ``b``: a ramp over ``table_coordinate``, and for a driven fit the ramps of the tabulated values weighed by
    ``Driven.weights`` (one ramp per tabulated value where the table is not zero)."""
    u = table_coordinate(b)
    if fit.driven is None:
        return lambda values: b.ramp(values, u)
    weights = fit.driven.weights(b)

    def interpolated(values):
        total = None  # the caller skips tables that are zero at every value
        for v, w in zip(values, weights):
            if v.max() > 0.0:
                term = b.scale(b.ramp(v, u), w) if fit.driven.kind == "float" else b.ramp(v, u) * w
                total = term if total is None else total + term
        return total

    return interpolated


def shade(b, mapping, p, fit: Fit, knot_backend) -> None:
    """The fitted mapping of ``p`` on backend ``b`` (module docstring), its colours folded into the tables where
    they follow the view's elevation alone (``folded_colours``; ``knot_backend(wo)``: a ``NumpyBackend`` of ``p``)."""
    scaled = ScaledBackend(b, fit, tables(b, fit))
    mapping.shade(scaled, p)
    scaled.flush(folded_colours(mapping, p, fit, knot_backend))
    for (kind, kw), weights in zip(fit.extras, fit.extra_weights):
        if weights.max() <= 0.0:
            continue
        color = scaled.table(weights)
        if kind == "ggx":
            b.glossy(color, kw["alpha"], kw["alpha"], b.normal())
        elif kind.endswith("_refraction"):  # "beckmann_refraction" in fits made before FITTER_VERSION 7
            b.refraction(color, kw["alpha"], kw["ior"], b.view() if kw["normal"] == "view" else b.normal(),
                         kind.removesuffix("_refraction"))
        else:  # diffuse, translucent, velvet, toons: the backend's method of that name takes the parameters
            getattr(b, kind)(color, **kw)
