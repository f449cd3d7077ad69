"""Anisotropic layered stack: Belcour 2018's adding loop with 2×2 covariances (paper: anisotropic_layered, Sec. 3).

Conventions: float64, vectorised numpy; ``eval(p, wi, wo)`` is the BRDF (no cosine) for light from ``wi`` seen from
``wo`` (local frame: x the surface tangent, z the normal), zero unless both are above the surface (the light the
stack transmits into a last, semi-infinite dielectric is not modelled). The model is built from the view: the
adding loop runs along the mean path of the view direction (cos θo), so every lobe's weight, roughness and tangent
are functions of cos θo and the interfaces alone, as a Cycles closure's must be (research notes §6). ``sample``
therefore draws ``wi`` given ``wo`` (``SAMPLES_FROM_VIEW``).

The BRDF is a sum of one lobe per interface, top first (a conductor ends the stack):

* the top interface's own reflection (``kind`` "surface"): the exact anisotropic GGX microfacet BRDF
  F(i·h) D(h) G2(i, o) / (4 cos θi cos θo) at its (αx, αy, tangent), with the exact Fresnel of a dielectric of
  IOR η or a conductor n + ik; a single interface is exactly this BRDF.
* interface j > 0 (``kind`` "reflection"): weight × D(h) G2(i, o) / (4 cos θi cos θo), the Fresnel-free
  anisotropic GGX (Cycles' ``microfacet("ggx", N, T, αu, αv, 1.0, 0)``) with the lobe's own tangent.

The adding loop (Belcour 2018 Sec. 5-6, as the public codes write it; the anisotropic paper's Sec. 3 replaces each
variance by a covariance Σ = R diag(σx, σy) Rᵀ in the surface's tangent frame, R the interface's rotation):

* variances σ = h(α) = α^1.1 / (1 − α^1.1) for reflection, h(s α) for transmission (α ≤ 0.9999, so that h is
  finite). Transmission roughness scale s: the public codes' (and the anisotropic paper's code's) choice with the
  cosines set to 1, s = |η12 − 1| / (2 η12) down and |1 − η12| / 2 up, not the paper prose's cosine-dependent
  scale; the Jacobians j12 = (cos θt / cos θi) η12 and j21 = 1 / j12 scale covariances like variances.
* energies per RGB channel: FGD looked up at the roughness accumulated above the interface (the covariance of the
  transmitted light plus the interface's reflection), R21 = R12, T = 1 − R (dielectric) or 0 (conductor), the
  inter-reflection denominator 1 / (1 − Ri0 R12) per channel (never averaged over RGB), total internal reflection
  on the way up by the tables' escaping fraction (Belcour's decoupling: what does not escape joins Ri0).
* covariances are one per lobe for all channels: the loop's scalar energy factors are channel means (the public
  codes' energy-weighted average over colours).
* geometry (mean cosines, Jacobians, s) uses the channel-mean IORs: η12 = mean(η below) / mean(η above); with a view
  from air the mean path never meets total internal reflection (η_j sin θ_j = sin θo).
* media between interfaces (Belcour's forward-scattering operator): transmittance (1 + τs / cos) e^{−τ / cos}
  (unscattered plus once forward-scattered light, τ = (σa + σs) depth, τs = σs depth) per channel at the mean
  cosine inside, and the Henyey-Greenstein variance ((1 − g) / g)^0.8 / (1 + g) (g ≥ 1e-3) weighted by the
  scattered share of the transmitted energy (Belcour's code adds it whatever σs: a clear absorbing layer would
  blur; ours does not).
* anisotropic FGD and TIR lookups take the isotropic equivalent of a covariance: α = sqrt((αu² + αv²) / 2) of its
  principal roughnesses, the root of the azimuthal mean of GGX's projected α² (the masking along the view's
  azimuth depends on α(φ)² = αu² cos²φ + αv² sin²φ). Measured against the azimuth-averaged anisotropic GGX albedo
  and FGD (η = 1.5; 60 random αu ∈ [0.02, 0.9], αv / αu ∈ [0.01, 1], μ ∈ [0.05, 1]), its error is RMS 0.012 and
  0.016 (max 0.025, 0.055), where sqrt(αu αv) gives 0.13 and 0.043 (max 0.36, 0.16) and h⁻¹(sqrt(det Σ)) 0.11 and
  0.031.
* a lobe's covariance is eigen-decomposed into its tangent angle φ = ½ atan2(2Σxy, Σxx − Σyy) and principal
  variances (λmax = mean + hypot, λmin = det / λmax, stable for near-isotropic and near-degenerate Σ), then
  (αu, αv) = h⁻¹(λ) clamped to [1e-4, 1].
* weights may not depend on the view's azimuth, but the albedo of an anisotropic GGX lobe does: it is bracketed
  (measured) by isotropic GGX at the roughnesses ``view_roughness_range`` gives, sqrt(sin²θo α² + cos²θo ᾱ²)
  with α = αv and αu, ᾱ² = (αu² + αv²) / 2 (the view's projected roughness matters in proportion to sin θo). Two
  choices take the upper end of that bracket, so that no stack gains energy:
  - the top interface's R12 (what the loop keeps from the light it sends below) is the larger FGD at the two
    ends: its lobe is the exact anisotropic BRDF, so what goes below never exceeds what the top leaves. Measured
    over 200 random (αu, αv / αu ∈ [1e-3, 1], μ) × 5 azimuths: the exact top's FGD exceeds this R12 by at most
    0.017 (η = 1.5), 0.007 (η = 3), 0.019 (gold), and falls below it by up to 0.76 at grazing views along the
    rough direction (RMS 0.12, 0.087, 0.044); FGD at ᾱ alone would be exceeded by up to 0.62.
  - lobe weight = energy / max(E(cos θo, α_low), E(cos θo, α_high)), E the tabulated directional albedo of the
    Fresnel-free GGX: FGD already counts what masking removes, and the GGX lobe the weight scales removes it
    again. An isotropic lobe renders its energy (up to the tables); an anisotropic one 0.66 to 1.02 times it
    (RMS deviation 0.048; E at ᾱ would give 0.70 to 1.12, RMS 0.029).
  Non-absorbing stacks over a mirror (k = 20): furnace albedo 0.9993 to 1.0002 for smooth ones (cos θo 1 to 0.1), at
  most 1.004 over 160 random stacks of 1-4 interfaces × 12 views; rough ones lose what G2 removes (α = 0.3 coat
  and mirror: 0.84 at normal view), strongly anisotropic ones what the bracket costs.

``lobes(ops, ...)`` computes all this once for any backend: the reference passes ``Float64Ops``, a Cycles mapping
its expression backend (only arithmetic, sqrt, exp, pow, atan2, cos/sin, min/max and the tables behind ops
methods). ``isotropic_lobes`` is Belcour's scalar-variance loop, transcribed separately: the identity test and
the cost benchmark compare against it. Tables: ``aniso_stack_tables`` (what they hold, their errors).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..models.aniso_stack import MIN_ALPHA, Params, params_from_dict  # noqa: F401  (the Python API)
from . import aniso_stack_tables, microfacet
from . import lobes as lobe_choice
from .frames import as_directions, normalize, reflect

SAMPLES_FROM_VIEW = True
MIN_COS = 1e-6  # the view cosine the loop starts from at least (exactly grazing views stay finite)
MAX_ALPHA = 0.9999  # h(α) is finite below 1
MIN_G = 1e-3  # the HG variance is finite above 0
TINY = 1e-30  # floor of denominators that vanish only with their numerators
QUADRATURE_NODES = 4096  # default node count of ``directional_albedo``


class Lobe(NamedTuple):
    """One term of the BRDF seen from the view: ``kind`` "surface" (the top interface, exact Fresnel) or
    "reflection", the ``interface`` it comes from, ``weight`` (colour; 1 for the surface), the GGX roughnesses
    ``alpha_u`` along the tangent at ``angle`` (radians about the normal from the surface tangent) and ``alpha_v``
    across it, and ``energy`` (colour): what the adding loop says it reflects, by which ``sample`` picks lobes."""

    kind: str
    interface: int
    weight: object
    alpha_u: object
    alpha_v: object
    angle: object
    energy: object


# ------------------------------------------------------------------------------- roughness and variance

def variance(ops, alpha):
    """h(α) = α^1.1 / (1 − α^1.1) (Belcour 2018 Sec. 5.1's fit), α clamped to ``MAX_ALPHA``."""
    a = ops.pow(ops.minimum(alpha, MAX_ALPHA), 1.1)
    return a / (1.0 - a)


def roughness(ops, v):
    """h⁻¹(v) = (v / (1 + v))^{1/1.1}, clamped to [1e-4, 1]."""
    return ops.minimum(ops.maximum(ops.pow(v / (1.0 + v), 1.0 / 1.1), MIN_ALPHA), 1.0)


def hg_variance(g: float) -> float:
    """Belcour's variance of a Henyey-Greenstein lobe, ((1 − g) / g)^0.8 / (1 + g), g ≥ ``MIN_G``."""
    g = max(g, MIN_G)
    return ((1.0 - g) / g) ** 0.8 / (1.0 + g)


def transmission_scales(n12: float) -> tuple[float, float]:
    """The roughness scales s of transmission down and up through an interface of relative IOR n12, with the
    public codes' cosines set to 1 (module docstring)."""
    return 0.5 * abs(n12 - 1.0) / n12, 0.5 * abs(1.0 - n12)


@dataclass(frozen=True)
class Covariance:
    """A symmetric 2×2 covariance [[xx, xy], [xy, yy]] in the surface's tangent frame; entries are backend floats."""

    xx: object
    xy: object
    yy: object
    __array_ufunc__ = None  # ndarray * Covariance defers to __rmul__

    def __add__(self, other: Covariance) -> Covariance:
        return Covariance(self.xx + other.xx, self.xy + other.xy, self.yy + other.yy)

    def __mul__(self, s) -> Covariance:
        return Covariance(self.xx * s, self.xy * s, self.yy * s)

    __rmul__ = __mul__

    def __truediv__(self, s) -> Covariance:
        return Covariance(self.xx / s, self.xy / s, self.yy / s)


ZERO = Covariance(0.0, 0.0, 0.0)


def oriented(sx, sy, cos_r, sin_r) -> Covariance:
    """R diag(σx, σy) Rᵀ for a frame rotated by (cos, sin) from the surface tangent (the paper's Σ, Sec. 3.1)."""
    return Covariance(sx * cos_r * cos_r + sy * sin_r * sin_r, (sx - sy) * cos_r * sin_r,
                      sx * sin_r * sin_r + sy * cos_r * cos_r)


def principal_variances(ops, cov: Covariance):
    """(λmax, λmin) of ``cov``: the mean plus the hypotenuse, then det / λmax (no cancellation when λmin ≪ λmax)."""
    half_difference = (cov.xx - cov.yy) * 0.5
    big = (cov.xx + cov.yy) * 0.5 + ops.sqrt(half_difference * half_difference + cov.xy * cov.xy)
    determinant = ops.maximum(cov.xx * cov.yy - cov.xy * cov.xy, 0.0)
    return big, determinant / ops.maximum(big, TINY)


def major_axis(ops, cov: Covariance):
    """The angle of the major axis of ``cov`` from the surface tangent, ½ atan2(2 Σxy, Σxx − Σyy)."""
    return 0.5 * ops.atan2(2.0 * cov.xy, cov.xx - cov.yy)


def equivalent_alpha(ops, cov: Covariance):
    """The isotropic equivalent roughness of a covariance: sqrt((αu² + αv²) / 2) of its principal roughnesses, the
    root of the azimuthal mean of GGX's projected α² (module docstring)."""
    big, small = principal_variances(ops, cov)
    return rms_alpha(ops, roughness(ops, big), roughness(ops, small))


def rms_alpha(ops, au, av):
    return ops.sqrt((au * au + av * av) * 0.5)


def view_roughness_range(ops, cos_view, au, av):
    """Isotropic roughnesses bracketing an anisotropic GGX surface seen at cos θo from any azimuth: the view's
    projected α² (between αv² and αu²) weighted by sin²θo, the azimuthal mean (αu² + αv²) / 2 by cos²θo (at normal
    incidence the azimuth does not matter)."""
    mean, sin2 = (au * au + av * av) * 0.5, 1.0 - cos_view * cos_view
    return ops.sqrt(sin2 * av * av + (1.0 - sin2) * mean), ops.sqrt(sin2 * au * au + (1.0 - sin2) * mean)


# ------------------------------------------------------------------------------- one interface

def _value(inputs: dict, name: str, j: int, default):
    """A texturable parameter of interface / medium j: the backend's value where ``inputs`` has one."""
    return inputs.get((name, j), default)


def _orientation(inputs: dict, interface, j: int):
    """αx, αy and the rotation (radians) of interface j."""
    ax = _value(inputs, "alpha_x", j, interface.alpha_x)
    ay = _value(inputs, "alpha_y", j, interface.alpha_y)
    return ax, ay, _value(inputs, "rotation", j, interface.rotation) * (math.pi / 180.0)


def _mean(values) -> float:
    return sum(values) / len(values)


def relative(interface, above: tuple) -> tuple:
    """The interface's relative IOR per channel (and extinction for a conductor), from the IOR ``above``."""
    return tuple(b / a for b, a in zip(interface.ior, above)), tuple(k / a for k, a in zip(interface.k, above))


def reflectance(ops, interface, above: tuple, cos_i, alpha):
    """R12 per channel: the FGD of the interface seen from above at cos θi and roughness α."""
    eta, k = relative(interface, above)
    if interface.type == "conductor":
        return ops.fgd_conductor(cos_i, alpha, eta, k)
    return ops.fgd_dielectric(cos_i, alpha, eta)


def top_reflectance(ops, interface, cos_view, ax, ay):
    """R12 of the top interface: the larger of its FGD at the two ends of ``view_roughness_range`` (module
    docstring), so that what the loop sends below does not exceed what the exact top leaves at any view azimuth."""
    air = (1.0, 1.0, 1.0)
    low, high = view_roughness_range(ops, cos_view, ax, ay)
    return ops.maximum(reflectance(ops, interface, air, cos_view, low),
                       reflectance(ops, interface, air, cos_view, high))


def refracted_cos(ops, cos_i, n12: float):
    """cos θt of the mean direction (Snell), kept ≥ ``MIN_COS``."""
    return ops.maximum(ops.sqrt(ops.maximum(1.0 - (1.0 - cos_i * cos_i) / (n12 * n12), 0.0)), MIN_COS)


def escape(ops, previous: tuple, above: tuple, cos_i, alpha):
    """The share of the light travelling up at cos θi that the interface above lets out (``tables.escape``)."""
    return ops.escape(cos_i, alpha, tuple(a / b for a, b in zip(previous, above)))


def empty(medium, j: int, inputs: dict) -> bool:
    """Whether medium j is an empty gap (depth 0, not a backend value)."""
    return medium.depth == 0.0 and ("depth", j) not in inputs


def medium_transmittance(ops, medium, j: int, inputs: dict, cos, n: int):
    """Belcour's medium operator at the mean cosine inside: the unscattered and the once forward-scattered
    transmittance (colours), e^{−τ / cos} and (τs / cos) e^{−τ / cos}."""
    depth = _value(inputs, "depth", j, medium.depth) / cos
    sigma_a = _value(inputs, "sigma_a", j, ops.color(medium.sigma_a, n))
    sigma_s = ops.color(medium.sigma_s, n)
    unscattered = ops.exp(ops.scale(sigma_a + sigma_s, -depth))
    return unscattered, unscattered * ops.scale(sigma_s, depth)


def scattered_variance(ops, medium, unscattered, scattered):
    """The HG variance weighted by the scattered share of the transmitted energy (channel means)."""
    share = ops.mean(scattered) / ops.maximum(ops.mean(unscattered + scattered), TINY)
    return share * hg_variance(medium.g)


# ------------------------------------------------------------------------------- the adding loop

class _Stack(NamedTuple):
    """What the interfaces above the current one do, seen along the view's mean path (Belcour's notation, 0 the
    top, i the current depth): energies T0i, Ti0, Ri0 (colours), covariances of transmission down and up and of
    reflection from below, the accumulated Jacobians, and the mean cosine in the current layer."""

    t0i: object
    ti0: object
    ri0: object
    cov_t0i: Covariance
    cov_ti0: Covariance
    cov_ri0: Covariance
    j0i: object
    ji0: object
    cos: object


def _top(cos_o) -> _Stack:
    return _Stack(1.0, 1.0, 0.0, ZERO, ZERO, ZERO, 1.0, 1.0, cos_o)


def lobes(ops, p: Params, cos_o, n: int, inputs: dict | None = None) -> list[Lobe]:
    """The BRDF's lobes for n views at cos θo (module docstring). ``inputs`` may replace texturable values by
    backend values: keys ("alpha_x", j), ("alpha_y", j), ("rotation", j) (degrees) of interface j, ("sigma_a", j)
    (colour) and ("depth", j) of medium j."""
    inputs = inputs or {}
    cos_view = ops.maximum(cos_o, MIN_COS)
    stack, above, previous, out = _top(cos_view), (1.0, 1.0, 1.0), (1.0, 1.0, 1.0), []
    for j, interface in enumerate(p.interfaces):
        ax, ay, angle = _orientation(inputs, interface, j)
        cos_r, sin_r = ops.cos(angle), ops.sin(angle)
        cov_r12 = oriented(variance(ops, ax), variance(ops, ay), cos_r, sin_r)
        if j == 0:
            r12 = top_reflectance(ops, interface, cos_view, ax, ay)
        else:
            alpha = equivalent_alpha(ops, stack.cov_t0i + cov_r12)
            r12 = reflectance(ops, interface, above, stack.cos, alpha)
            stack = _escape_upwards(ops, stack, escape(ops, previous, above, stack.cos, alpha))
        inverse = 1.0 / ops.maximum(1.0 - stack.ri0 * r12, TINY)  # per channel
        loop = ops.mean(stack.ri0 * r12 * inverse)
        energy = stack.t0i * r12 * stack.ti0 * inverse
        if j == 0:
            out.append(Lobe("surface", 0, ops.color((1.0, 1.0, 1.0), n), ax, ay, angle, energy))
        else:
            cov = stack.cov_ti0 + (stack.cov_t0i + cov_r12 + (cov_r12 + stack.cov_ri0) * loop) * stack.j0i
            out.append(_reflection_lobe(ops, j, cos_view, energy, cov))
        if j == len(p.interfaces) - 1:
            return out
        n12 = _mean(interface.ior) / _mean(above)
        stack = _add_dielectric(ops, stack, r12, cov_r12, inverse, loop, n12, (ax, ay, cos_r, sin_r))
        stack = _through_medium(ops, stack, p.media[j], j, inputs, n)
        previous, above = above, interface.ior
    return out


def _reflection_lobe(ops, j: int, cos_view, energy, cov: Covariance) -> Lobe:
    """The lobe of covariance ``cov``, weighted by its energy over its GGX albedo (module docstring)."""
    big, small = principal_variances(ops, cov)
    au, av = roughness(ops, big), roughness(ops, small)
    return Lobe("reflection", j, ops.scale(energy, 1.0 / lobe_albedo(ops, cos_view, au, av)), au, av,
                major_axis(ops, cov), energy)


def lobe_albedo(ops, cos_view, au, av):
    """The larger of E at the two ends of ``view_roughness_range`` (≥ 1e-3): about the largest albedo of the
    anisotropic lobe over the view's azimuths (module docstring)."""
    low, high = view_roughness_range(ops, cos_view, au, av)
    return ops.maximum(ops.maximum(ops.ggx_albedo(cos_view, low), ops.ggx_albedo(cos_view, high)), 1e-3)


def _escape_upwards(ops, stack: _Stack, escaping) -> _Stack:
    """Belcour's TIR decoupling: what the interfaces above do not let out is reflected back down."""
    return stack._replace(ri0=ops.minimum(stack.ri0 + stack.ti0 * (1.0 - escaping), 1.0),
                          ti0=stack.ti0 * escaping)


def _add_dielectric(ops, stack: _Stack, r12, cov_r12, inverse, loop, n12: float, orientation) -> _Stack:
    """The adding operator for a dielectric interface below the stack (energies and covariances), then the mean
    path refracted into the layer below it."""
    ax, ay, cos_r, sin_r = orientation
    s_down, s_up = transmission_scales(n12)
    cov_t12 = oriented(variance(ops, ax * s_down), variance(ops, ay * s_down), cos_r, sin_r)
    cov_t21 = oriented(variance(ops, ax * s_up), variance(ops, ay * s_up), cos_r, sin_r)
    cos_t = refracted_cos(ops, stack.cos, n12)
    j12 = cos_t / stack.cos * n12
    t12 = 1.0 - r12
    back = t12 * stack.ri0 * t12 * inverse  # m_Ri0: down through the interface, back up from the stack above
    reflected = cov_r12 * ops.mean(r12) + (cov_t12 + (cov_t21 + stack.cov_ri0 + (cov_r12 + stack.cov_ri0) * loop)
                                           * j12) * ops.mean(back)
    spread = cov_r12 + stack.cov_ri0
    return _Stack(t0i=stack.t0i * t12 * inverse, ti0=t12 * stack.ti0 * inverse, ri0=r12 + back,
                  cov_t0i=stack.cov_t0i * j12 + cov_t12 + spread * (j12 * loop),
                  cov_ti0=cov_t21 * stack.ji0 + stack.cov_ti0 + spread * (stack.ji0 * loop),
                  cov_ri0=reflected / ops.maximum(ops.mean(r12 + back), TINY),
                  j0i=stack.j0i * j12, ji0=stack.ji0 / j12, cos=cos_t)


def _through_medium(ops, stack: _Stack, medium, j: int, inputs: dict, n: int) -> _Stack:
    """The adding operator for a medium layer (no reflection): energies attenuated, covariances widened by the
    scattered light (none for a clear medium); nothing for an empty gap."""
    if empty(medium, j, inputs):
        return stack
    unscattered, scattered = medium_transmittance(ops, medium, j, inputs, stack.cos, n)
    through = unscattered + scattered
    stack = stack._replace(t0i=stack.t0i * through, ti0=stack.ti0 * through, ri0=stack.ri0 * through * through)
    if not any(medium.sigma_s):
        return stack
    v = scattered_variance(ops, medium, unscattered, scattered)
    spread = Covariance(v, 0.0, v)
    return stack._replace(cov_t0i=stack.cov_t0i + spread, cov_ti0=stack.cov_ti0 + spread * stack.ji0,
                          cov_ri0=stack.cov_ri0 + spread * 2.0)


# ------------------------------------------------------------------------------- Belcour's scalar loop

def isotropic_lobes(ops, p: Params, cos_o, n: int, inputs: dict | None = None) -> list[Lobe]:
    """Belcour's loop with scalar variances (each interface at its isotropic equivalent sqrt((αx² + αy²) / 2),
    tangent angles 0), a separate transcription of ``lobes``' recipe: the two agree for isotropic interfaces (any
    rotations)."""
    inputs = inputs or {}
    cos_view = ops.maximum(cos_o, MIN_COS)
    cos_i, t0i, ti0, ri0, s_t0i, s_ti0, s_ri0, j0i, ji0 = cos_view, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0
    above, previous, out = (1.0, 1.0, 1.0), (1.0, 1.0, 1.0), []
    for j, interface in enumerate(p.interfaces):
        ax, ay, _ = _orientation(inputs, interface, j)
        a = rms_alpha(ops, ax, ay)
        s_r12 = variance(ops, a)
        if j == 0:
            r12 = top_reflectance(ops, interface, cos_i, ax, ay)
        else:
            alpha = roughness(ops, s_t0i + s_r12)
            r12 = reflectance(ops, interface, above, cos_i, alpha)
            out_share = escape(ops, previous, above, cos_i, alpha)
            ri0, ti0 = ops.minimum(ri0 + ti0 * (1.0 - out_share), 1.0), ti0 * out_share
        denominator = ops.maximum(1.0 - ri0 * r12, TINY)
        m_rr = ops.mean(ri0 * r12 / denominator)
        energy = t0i * r12 * ti0 / denominator
        if j == 0:
            out.append(Lobe("surface", 0, ops.color((1.0, 1.0, 1.0), n), a, a, 0.0, energy))
        else:
            lobe_alpha = roughness(ops, s_ti0 + j0i * (s_t0i + s_r12 + m_rr * (s_r12 + s_ri0)))
            weight = ops.scale(energy, 1.0 / lobe_albedo(ops, cos_view, lobe_alpha, lobe_alpha))
            out.append(Lobe("reflection", j, weight, lobe_alpha, lobe_alpha, 0.0, energy))
        if j == len(p.interfaces) - 1:
            return out
        n12 = _mean(interface.ior) / _mean(above)
        s_down, s_up = transmission_scales(n12)
        s_t12, s_t21 = variance(ops, a * s_down), variance(ops, a * s_up)
        cos_t = refracted_cos(ops, cos_i, n12)
        j12, j21 = cos_t / cos_i * n12, cos_i / cos_t / n12
        t12 = 1.0 - r12
        m_ri0 = t12 * ri0 * t12 / denominator
        e_ri0 = r12 + m_ri0
        s_ri0_next = ops.mean(r12) * s_r12 + ops.mean(m_ri0) * (s_t12 + j12 * (s_t21 + s_ri0 + m_rr * (s_r12 + s_ri0)))
        s_t0i = j12 * s_t0i + s_t12 + j12 * (s_r12 + s_ri0) * m_rr
        s_ti0 = ji0 * s_t21 + s_ti0 + ji0 * (s_r12 + s_ri0) * m_rr
        s_ri0 = s_ri0_next / ops.maximum(ops.mean(e_ri0), TINY)
        t0i, ti0, ri0 = t0i * t12 / denominator, t12 * ti0 / denominator, e_ri0
        j0i, ji0, cos_i = j0i * j12, ji0 * j21, cos_t
        previous, above = above, interface.ior
        if empty(p.media[j], j, inputs):
            continue
        unscattered, scattered = medium_transmittance(ops, p.media[j], j, inputs, cos_i, n)
        through = unscattered + scattered
        t0i, ti0, ri0 = t0i * through, ti0 * through, ri0 * through * through
        if any(p.media[j].sigma_s):
            v = scattered_variance(ops, p.media[j], unscattered, scattered)
            s_t0i, s_ti0, s_ri0 = s_t0i + v, s_ti0 + ji0 * v, s_ri0 + 2.0 * v
    return out


class Float64Ops:
    """The operations ``lobes`` needs (the protocol a backend implements), in float64 numpy: floats (N,) or
    constants, colours (N, 3). Arithmetic is Python's operators; besides: exp, sqrt, pow, cos, sin, atan2, maximum,
    minimum, mean (of a colour's channels), scale (colour × float), color (a constant colour), and the tables:
    fgd_dielectric(cos, α, η) and fgd_conductor(cos, α, η, k) (colours; η, k constant per channel), escape(cos,
    α, η) (colour), ggx_albedo(cos, α) (float)."""

    exp, sqrt, cos, sin = np.exp, np.sqrt, np.cos, np.sin
    atan2, pow = staticmethod(np.arctan2), staticmethod(np.power)
    maximum, minimum = staticmethod(np.maximum), staticmethod(np.minimum)

    @staticmethod
    def mean(color):
        return np.mean(color, axis=-1)

    @staticmethod
    def scale(color, s):
        return np.asarray(color, dtype=float) * np.asarray(s, dtype=float)[..., None]

    @staticmethod
    def color(values, n):
        return np.broadcast_to(np.asarray(values, dtype=float), (n, 3)).copy()

    @staticmethod
    def fgd_dielectric(cos, alpha, eta):
        return aniso_stack_tables.load().fgd(cos, alpha, eta)

    @staticmethod
    def fgd_conductor(cos, alpha, eta, k):
        return aniso_stack_tables.load().conductor_fgd(cos, alpha, eta, k)

    @staticmethod
    def escape(cos, alpha, eta):
        return aniso_stack_tables.load().escape(cos, alpha, eta)

    @staticmethod
    def ggx_albedo(cos, alpha):
        return aniso_stack_tables.load().albedo(cos, alpha)


F64 = Float64Ops()


# ------------------------------------------------------------------------------- anisotropic GGX

def _into(w, angle):
    """Directions w in the frame of a lobe whose tangent is at ``angle`` from the surface tangent."""
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * w[:, 0] + s * w[:, 1], c * w[:, 1] - s * w[:, 0], w[:, 2]], axis=1)


def _out_of(w, angle):
    return _into(w, -np.asarray(angle))


def _stretched(w, ax, ay):
    """(αx x, αy y, z): Λ and the visible normals of GGX (αx, αy) are those of GGX 1 in these coordinates."""
    return np.stack([ax * w[:, 0], ay * w[:, 1], w[:, 2]], axis=1)


def ggx_d(m, ax, ay):
    """Anisotropic GGX D(m) = 1 / (π αx αy (x²/αx² + y²/αy² + z²)²) in the lobe's frame, zero below."""
    return microfacet.ggx_d(np.stack([m[:, 0] / ax, m[:, 1] / ay, m[:, 2]], axis=1), 1.0) / (ax * ay)


def ggx_g2(wi, wo, ax, ay):
    """Height-correlated Smith G2 of anisotropic GGX in the lobe's frame."""
    return microfacet.g2(_stretched(wi, ax, ay), _stretched(wo, ax, ay), 1.0)


def ggx_reflection_pdf(wi, wo, ax, ay):
    """Density of wi = reflect(wo, m), m a visible normal for wo: D_wo(h) / (4 wo·h) = D(h) / (2 (cos θo +
    |stretched wo|)) (cos θo (1 + Λ(wo)) in a grazing-safe form)."""
    h = normalize(wi + wo)
    return ggx_d(h, ax, ay) / (2.0 * (wo[:, 2] + np.linalg.norm(_stretched(wo, ax, ay), axis=1)))


def ggx_sample(wo, ax, ay, u1, u2):
    """Reflect wo (above, lobe frame) about a visible normal of anisotropic GGX (Heitz 2018 in stretched space)."""
    visible = microfacet.sample_vndf(normalize(_stretched(wo, ax, ay)), 1.0, u1, u2)
    return reflect(wo, normalize(_stretched(visible, ax, ay)))


def top_fresnel(interface, cos):
    """The exact Fresnel reflectance of the top interface (from air) per channel, (N, 3)."""
    if interface.type == "conductor":
        return microfacet.fresnel_conductor(cos, interface.ior, interface.k)
    by_ior = {eta: microfacet.fresnel_dielectric(cos, eta) for eta in set(interface.ior)}
    return np.stack([by_ior[eta] for eta in interface.ior], axis=1)


# ------------------------------------------------------------------------------- evaluation

class Sample(NamedTuple):
    """Sampled light directions ``wi`` for each view, with weight f |cos wi| / pdf, and pdf."""

    wi: np.ndarray
    weight: np.ndarray
    pdf: np.ndarray


def lobes_at(p: Params, wo) -> list[Lobe]:
    """The lobes (float64) for views ``wo`` (N, 3) above the surface."""
    return lobes(F64, p, wo[:, 2], len(wo))


def lobe_value(p: Params, lobe: Lobe, wi, wo):
    """One lobe's f(wi, wo) (N, 3), zero unless both directions are above (module docstring)."""
    a, b = _into(wi, lobe.angle), _into(wo, lobe.angle)
    up = (a[:, 2] > 0.0) & (b[:, 2] > 0.0)
    ci, co = np.where(up, a[:, 2], 1.0), np.where(up, b[:, 2], 1.0)
    h = normalize(a + b)
    dg = ggx_d(h, lobe.alpha_u, lobe.alpha_v) * ggx_g2(a, b, lobe.alpha_u, lobe.alpha_v) / (4.0 * ci * co)
    if lobe.kind == "surface":
        value = top_fresnel(p.interfaces[0], np.einsum("ij,ij->i", a, h)) * dg[:, None]
    else:
        value = lobe.weight * dg[:, None]
    return np.where(up[:, None], value, 0.0)


def _above(wi, wo):
    """The directions as (N, 3) arrays and the rows whose view is above the surface."""
    wi, wo = np.broadcast_arrays(as_directions(wi), as_directions(wo))
    return wi, wo, wo[:, 2] > 0.0


def eval(p: Params, wi, wo):
    """The BRDF f(wi, wo) (N, 3), no cosine: the sum of the lobes."""
    wi, wo, rows = _above(wi, wo)
    out = np.zeros((len(wo), 3))
    if rows.any():
        a, b = wi[rows], wo[rows]
        out[rows] = sum(lobe_value(p, lobe, a, b) for lobe in lobes_at(p, b))
    return out


# ------------------------------------------------------------------------------- sampling

def _lobe_probabilities(found: list[Lobe]):
    """(N, L) probabilities of picking each lobe: its energy, channel-averaged (floored, so that every lobe the
    pdf counts can be drawn)."""
    e = np.stack([np.maximum(np.mean(lobe.energy, axis=1), 1e-9) for lobe in found], axis=1)
    return e / e.sum(axis=1, keepdims=True)


def lobe_pdf(lobe: Lobe, wi, wo):
    """Density of wi drawn from the lobe's own sampler (``ggx_sample``) for views wo above."""
    return ggx_reflection_pdf(_into(wi, lobe.angle), _into(wo, lobe.angle), lobe.alpha_u, lobe.alpha_v)


def lobe_sample(lobe: Lobe, wo, u1, u2):
    return _out_of(ggx_sample(_into(wo, lobe.angle), lobe.alpha_u, lobe.alpha_v, u1, u2), lobe.angle)


def pdf(p: Params, wi, wo):
    """Solid-angle density (N,) of ``sample``'s wi given wo (0 for views below the surface)."""
    wi, wo, rows = _above(wi, wo)
    out = np.zeros(len(wo))
    if rows.any():
        a, b = wi[rows], wo[rows]
        found = lobes_at(p, b)
        prob = _lobe_probabilities(found)
        out[rows] = sum(prob[:, k] * lobe_pdf(lobe, a, b) for k, lobe in enumerate(found))
    return out


def _rows(lobe: Lobe, m) -> Lobe:
    """The lobe restricted to the rows ``m`` (per-row fields; constants stay)."""
    return lobe._replace(**{f: np.broadcast_to(np.asarray(getattr(lobe, f)), m.shape)[m]
                            for f in ("alpha_u", "alpha_v", "angle")})


def sample(p: Params, wo, u) -> Sample:
    """Sample wi for each view wo from u in [0, 1)^3: u0 picks a lobe by its energy (``_lobe_probabilities``),
    (u1, u2) a visible normal of its anisotropic GGX, about which wo is reflected. Views below the surface get
    wi = −wo, weight and pdf 0."""
    wo, u = as_directions(wo), as_directions(u)
    wi = -wo
    rows = wo[:, 2] > 0.0
    if rows.any():
        b, v = wo[rows], u[rows]
        found = lobes_at(p, b)
        pick, _, _ = lobe_choice.choose(_lobe_probabilities(found), v[:, 0])
        drawn = np.empty_like(b)
        for k, lobe in enumerate(found):
            m = pick == k
            if m.any():
                drawn[m] = lobe_sample(_rows(lobe, m), b[m], v[m, 1], v[m, 2])
        wi[rows] = drawn
    density = pdf(p, wi, wo)
    value = eval(p, wi, wo) * np.abs(wi[:, 2:])
    weight = np.divide(value, density[:, None], out=np.zeros_like(value), where=density[:, None] > 0)
    return Sample(wi, weight, density)


def _square_nodes(n: int):
    """About n quadrature nodes of the unit square: Gauss-Legendre in u1 (the visible normal's radius), the
    midpoint rule in u2 (its azimuth, periodic)."""
    k = max(int(round(np.sqrt(n))), 1)
    x, w = np.polynomial.legendre.leggauss(k)
    u1, u2 = np.meshgrid(0.5 * (x + 1.0), (np.arange(k) + 0.5) / k, indexing="ij")
    return u1.ravel(), u2.ravel(), np.repeat(0.5 * w / k, k)


def directional_albedo(p: Params, wo, n: int = QUADRATURE_NODES):
    """∫ f(wi, wo) cos θi dwi (N, 3) by quadrature: each lobe over its own visible normals (``_square_nodes``),
    f cos / pdf of its sampler. Zero for views below the surface."""
    wo = as_directions(wo)
    u1, u2, w = _square_nodes(n)
    albedo = np.zeros((len(wo), 3))
    for row in np.flatnonzero(wo[:, 2] > 0.0):
        view = np.repeat(wo[row:row + 1], len(w), axis=0)
        for lobe in lobes_at(p, view[:1]):
            x = lobe_sample(lobe, view, u1, u2)
            density = lobe_pdf(lobe, x, view)[:, None]
            value = lobe_value(p, lobe, x, view) * np.maximum(x[:, 2:], 0.0)
            albedo[row] += np.sum(w[:, None] * np.divide(value, density, out=np.zeros_like(value),
                                                         where=density > 0), axis=0)
    return albedo


def furnace_albedo(p: Params, wo, n: int = QUADRATURE_NODES):
    """What a white furnace returns towards wo (N, 3): the directional albedo (the model has no Dirac)."""
    return directional_albedo(p, wo, n)
