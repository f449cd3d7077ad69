"""Differentiable SpongeCake single scattering in torch (float64), batched over parameter sets.

The same model, conventions and formulas as ``addon.reference.spongecake.eval`` for stacks without a substrate
(Wang et al. 2022, Sec. 4; research notes Sec. 1), written with torch operations only so that a training loss can
evaluate f_ss(params') for network-predicted parameters and back-propagate into them.

API
---
``LayerBatch(kind, roughness, albedo, thickness, f0, orientation)``
    One layer of B parameter sets, every field a tensor with leading batch dimension B:
    ``kind`` (B,) long (0 surface, 1 fiber, 2 hg; ``KIND`` maps the reference's type names), ``roughness`` (B,)
    (SGGX alpha for flakes, the HG mean cosine g for hg), ``albedo`` (B, 3), ``thickness`` (B,) optical
    thickness T rho, ``f0`` (B, 3) Schlick reflectance (ignored by hg layers; f0 = 1 gives F = 1), and
    ``orientation`` (B, 3) flake normal / fiber tangent (normalised here; ignored by hg layers). Kinds may
    differ across the batch.

``eval_stack(layers, wi, wo) -> (B, N, 3)``
    f(wi, wo) without cosine and without the Dirac of delta transmission, for ``layers`` a list of
    LayerBatch, top layer first (1 or more layers, all with the same B). ``wi`` (light) and ``wo`` (viewer)
    are unit directions in the local frame (z = macro normal), (B, N, 3) or (N, 3) (broadcast over B); float64
    unless ``wi`` is a tensor of another float type (training in float32).
    Reflection and transmission, light from either side: layer k's lobe is attenuated along each direction by
    the layers between it and the side the direction points to. Zero when a direction is exactly grazing,
    and the flake lobes vanish where wo = -wi exactly (no half vector), as in the reference.

``from_params(params_list, device=None) -> list[LayerBatch]``
    B reference ``Params`` (same layer count, no substrate; the delta-transmission flag is irrelevant to
    ``eval``) to one LayerBatch per layer.

Differentiability: w.r.t. roughness, albedo, thickness, f0 and orientation, with finite gradients also for
very thick layers (T rho = 1e4) and near-grazing directions (|cos| = 1e-6). Every ``torch.where`` selects
between branches evaluated on safe inputs (grazing cosines replaced by 1, the hg rows' roughness replaced in the
flake branch and vice versa, the undefined half vector replaced by +z, the 0/0 of G's expm1 factor by 1), so no
NaN or inf gradient leaks through a mask.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

__all__ = ["KIND", "LayerBatch", "eval_stack", "from_params", "projected_area"]

KIND = {"surface": 0, "fiber": 1, "hg": 2}
SURFACE, FIBER, HG = 0, 1, 2
DTYPE = torch.float64


@dataclass
class LayerBatch:
    """One layer for B parameter sets (see the module docstring)."""

    kind: torch.Tensor  # (B,) long
    roughness: torch.Tensor  # (B,)
    albedo: torch.Tensor  # (B, 3)
    thickness: torch.Tensor  # (B,)
    f0: torch.Tensor  # (B, 3)
    orientation: torch.Tensor  # (B, 3)

    def __len__(self) -> int:
        return self.roughness.shape[0]


def from_params(params_list, device=None) -> list[LayerBatch]:
    """Reference ``Params`` (all with the same number of layers, no substrate) to one LayerBatch per layer."""
    params_list = list(params_list)
    if not params_list:
        raise ValueError("from_params: empty parameter list")
    n_layers = len(params_list[0].layers)
    for p in params_list:
        if p.substrate is not None:
            raise ValueError("from_params: stacks with a substrate are not supported")
        if len(p.layers) != n_layers:
            raise ValueError("from_params: all parameter sets must have the same number of layers")

    def tensor(values):
        return torch.tensor(values, dtype=DTYPE, device=device)

    batches = []
    for k in range(n_layers):
        layers = [p.layers[k] for p in params_list]
        batches.append(LayerBatch(
            kind=torch.tensor([KIND[layer.type] for layer in layers], dtype=torch.long, device=device),
            roughness=tensor([float(layer.roughness) for layer in layers]),
            albedo=tensor([[float(c) for c in layer.albedo] for layer in layers]),
            thickness=tensor([float(layer.thickness) for layer in layers]),
            f0=tensor([[float(c) for c in layer.f0] for layer in layers]),
            orientation=tensor([[float(c) for c in layer.orientation] for layer in layers]),
        ))
    return batches


# ----------------------------------------------------------------------------------------------- helpers

def _dot(a, b):
    return (a * b).sum(-1)


def _forms(axis, x):
    """|x x axis|^2 and (x . axis)^2 for unit ``axis``: x^T S x = a |x x axis|^2 + b (x . axis)^2 with no
    cancellation (the reference's frame coordinates across and along the axis)."""
    cross = torch.linalg.cross(x, axis.expand_as(x), dim=-1)
    along = _dot(x, axis)
    return _dot(cross, cross), along * along


class _Layer:
    """Per-layer quantities broadcast to (B, 1[, 3]) and made safe for both the flake and the hg branch."""

    def __init__(self, layer: LayerBatch):
        kind = layer.kind.reshape(-1, 1)
        self.is_hg = kind == HG
        self.is_flake = ~self.is_hg
        r = layer.roughness.reshape(-1, 1)
        # flake branch: alpha (a safe 0.5 on hg rows, whose g may be 0 or negative)
        alpha = torch.where(self.is_hg, torch.full_like(r, 0.5), r)
        a2 = alpha * alpha
        one = torch.ones_like(a2)
        surface = kind == SURFACE
        self.a = torch.where(surface, a2, one)  # eigenvalue across the axis
        self.b = torch.where(surface, one, a2)  # eigenvalue along the axis
        self.sqrt_det = self.a * torch.sqrt(self.b)  # sqrt(a^2 b)
        # hg branch: g (a safe 0 on flake rows)
        self.g = torch.where(self.is_hg, r, torch.zeros_like(r))
        o = layer.orientation.reshape(-1, 1, 3)
        self.axis = o / torch.sqrt(_dot(o, o)).unsqueeze(-1)
        self.albedo = layer.albedo.reshape(-1, 1, 3)
        self.f0 = layer.f0.reshape(-1, 1, 3)
        self.thickness = layer.thickness.reshape(-1, 1)

    def sigma(self, w):
        """Projected area sigma(w) = sqrt(w^T S w) for flakes, 1 for hg media, (B, N)."""
        across, along = _forms(self.axis, w)
        s = torch.sqrt(self.a * across + self.b * along)
        return torch.where(self.is_hg, torch.ones_like(s), s)

    def phase_value(self, wi, wo, h, valid, sigma_i):
        """F(h) f_p(wi -> wo), (B, N, 3): SGGX D(h) / (4 sigma(wi)) with Schlick's F on |wi . h|, or HG."""
        across, along = _forms(self.axis, h)
        q = across / self.a + along / self.b
        flake = 1.0 / (math.pi * self.sqrt_det * q * q * 4.0 * sigma_i)
        flake = torch.where(valid, flake, torch.zeros_like(flake))
        g = self.g
        base = 1.0 + g * g + 2.0 * g * _dot(wi, wo)  # cos theta = -wi . wo
        hg = (1.0 - g * g) / (4.0 * math.pi * base * torch.sqrt(base))
        c = torch.clamp(torch.abs(_dot(wi, h)), 0.0, 1.0).unsqueeze(-1)
        fresnel = self.f0 + (1.0 - self.f0) * (1.0 - c) ** 5
        flake3 = fresnel * flake.unsqueeze(-1)
        hg3 = hg.unsqueeze(-1).expand_as(flake3)
        return torch.where(self.is_flake.unsqueeze(-1), flake3, hg3)


def _slab_g(trho, lam_i, lam_o):
    """G of Eqs. 12 and 14 without overflow: (e^{T rho E-} - e^{-T rho E+}) / (Lambda_i + Lambda_o), with the
    expm1 form exact when Lambda_i + Lambda_o -> 0 (G -> T rho e^{T rho E-})."""
    zero = torch.zeros_like(lam_i)
    e_neg = torch.minimum(lam_i, zero) + torch.minimum(lam_o, zero)
    e_pos = torch.maximum(lam_i, zero) + torch.maximum(lam_o, zero)
    x = trho * torch.abs(e_pos + e_neg)
    positive = x > 0
    safe = torch.where(positive, x, torch.ones_like(x))
    factor = torch.where(positive, -torch.expm1(-safe) / safe, torch.ones_like(x))
    return trho * torch.exp(trho * torch.maximum(e_neg, -e_pos)) * factor


def _between(depths, up):
    """Per layer, the optical depth of the layers between it and the side each direction points to, (B, N)."""
    zero = torch.zeros_like(depths[0])
    out = []
    for k in range(len(depths)):
        above = sum(depths[:k], zero)
        below = sum(depths[k + 1:], zero)
        out.append(torch.where(up, above, below))
    return out


# ------------------------------------------------------------------------------------------------ public

def projected_area(layer: LayerBatch, w):
    """sigma(w) (B, N) of one layer's scatterers along unit directions w (B, N, 3): sqrt(w^T S w), 1 for hg."""
    return _Layer(layer).sigma(w)


def eval_stack(layers: list[LayerBatch], wi, wo):
    """SpongeCake single scattering f(wi, wo), (B, N, 3): see the module docstring."""
    if not layers:
        raise ValueError("eval_stack: needs at least one layer")
    batch = len(layers[0])
    dtype = wi.dtype if torch.is_tensor(wi) and wi.is_floating_point() else DTYPE
    wi, wo = torch.broadcast_tensors(torch.as_tensor(wi, dtype=dtype), torch.as_tensor(wo, dtype=dtype))
    if wi.dim() == 2:
        wi, wo = wi.expand(batch, -1, -1), wo.expand(batch, -1, -1)
    ci, co = wi[..., 2], wo[..., 2]
    grazing = (ci == 0) | (co == 0)
    one = torch.ones_like(ci)
    ci, co = torch.where(grazing, one, ci), torch.where(grazing, one, co)  # safe; those rows end as 0
    up_i, up_o = ci >= 0, co >= 0
    abs_ci, abs_co = torch.abs(ci), torch.abs(co)

    h = wi + wo
    valid = torch.any(h != 0, dim=-1)
    h = torch.where(valid.unsqueeze(-1), h, torch.tensor([0.0, 0.0, 1.0], dtype=dtype, device=h.device))
    h = h / torch.sqrt(_dot(h, h)).unsqueeze(-1)

    ls = [_Layer(layer) for layer in layers]
    sig_i = [layer.sigma(wi) for layer in ls]
    sig_o = [layer.sigma(wo) for layer in ls]
    between_i = _between([layer.thickness * s / abs_ci for layer, s in zip(ls, sig_i)], up_i)
    between_o = _between([layer.thickness * s / abs_co for layer, s in zip(ls, sig_o)], up_o)

    total = 0.0
    for k, layer in enumerate(ls):
        g = _slab_g(layer.thickness, sig_i[k] / ci, sig_o[k] / co)
        scale = sig_i[k] * g * torch.exp(-(between_i[k] + between_o[k])) / (abs_ci * abs_co)
        total = total + layer.albedo * layer.phase_value(wi, wo, h, valid, sig_i[k]) * scale.unsqueeze(-1)
    return torch.where(grazing.unsqueeze(-1), torch.zeros_like(total), total)
