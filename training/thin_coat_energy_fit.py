"""Fit ``addon.nodes.thin_coat.ENERGY_FIT``: the constants (c, q, l1, l2) of ``energy_ratio``, the energy of an ENDF
reflection lobe over that of the Beckmann closure rendering it (about ``endf_axis``), against quadratures on a grid of
views and concentrations, minimising the largest relative error (an L16 norm, Adam in torch, float64). Prints the
constants and ``energy_ratio_error`` (the unit tests' grid) with them.

    python -m training.thin_coat_energy_fit            # about a minute on 2 cores
"""
from __future__ import annotations

import numpy as np
import torch

from addon.nodes import closures_np
from addon.nodes import thin_coat as mapping
from addon.nodes.expr import NumpyBackend

GRID = (24, 25)  # views in [0.005, 1], concentrations in [0.01, 1e4], geometric
STEPS = 3000


def targets():
    """(µ, κ̂, α, exact ratio) on ``GRID``."""
    m, k = (a.ravel() for a in np.meshgrid(np.geomspace(0.005, 1.0, GRID[0]), np.geomspace(0.01, 1e4, GRID[1]),
                                           indexing="ij"))
    wo = np.stack([np.sqrt(1.0 - m * m), np.zeros_like(m), m], axis=1)
    b = NumpyBackend(wo, {})
    alpha = mapping.lobe_alpha(b, k)
    albedo = closures_np.beckmann_reflection_albedo(wo, alpha, normal=mapping.endf_axis(b, m, k))[:, 0]
    return m, k, alpha, mapping.endf_energy(m, k) / albedo


class TorchMath:
    """The backend operations ``energy_ratio`` uses, on torch tensors (so the fit differentiates the shader's own
    expression)."""
    exp, sqrt = staticmethod(torch.exp), staticmethod(torch.sqrt)

    @staticmethod
    def log(x):
        return torch.log(torch.clamp(x, min=1e-30))  # s = 0 at normal view, where the term is 1 anyway

    @staticmethod
    def maximum(x, y):
        return torch.clamp(x, min=y)


def fit() -> tuple[float, ...]:
    m, k, alpha, exact = (torch.tensor(a, dtype=torch.float64) for a in targets())
    params = torch.tensor(mapping.ENERGY_FIT, dtype=torch.float64, requires_grad=True)
    optimiser = torch.optim.Adam([params], lr=3e-3)
    saved = mapping.ENERGY_FIT
    try:
        mapping.ENERGY_FIT = params  # ``energy_ratio`` reads its constants from the module
        for _ in range(STEPS):
            optimiser.zero_grad()
            error = mapping.energy_ratio(TorchMath, m, k, alpha) / exact - 1.0
            loss = torch.mean(error ** 16) ** (1.0 / 16.0)
            loss.backward()
            optimiser.step()
    finally:
        mapping.ENERGY_FIT = saved
    return tuple(round(float(x), 4) for x in params.detach())


def main() -> None:
    constants = fit()
    print(f"ENERGY_FIT = {constants}  # c, q, l1, l2")
    mapping.ENERGY_FIT = constants
    print(f"energy_ratio_error: {mapping.energy_ratio_error():.4f}")


if __name__ == "__main__":
    main()
