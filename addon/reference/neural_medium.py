"""Neural participating media (Ge et al.; paper: neural_media), bpy-free: the networks' numpy inference and the
per-material table reconstruction (Sec. 3.7).

Two networks, ``double`` and ``multiple``, each an MLP 6-50-50-1 with tanh (Sec. 3.5; ``bake.mlp``), predict
log(1 + Phi) of the tables that ``training/medium_tracer.py`` defines: Phi(rho, z, theta, phi; albedo, g), the
radiance emitted per unit volume into direction (theta, phi) at the point (rho, z) by the double (order 2) or
multiple (orders >= 3) scattering of a unit point-directional source along +z in an infinite medium, lengths in
mean free paths (sigma_t = 1), directions in the point's local frame (theta from +z, phi from the radial direction,
folded to [0, pi]). Reconstruction: Phi = max(exp(network) - 1, 0).

Inputs reach the networks in [0, 1] through ``encode``, whose constants travel in each weights file's manifest
(``encoding``): rho and z through the same sinh map as the training grid (uniform near the source, geometric far
away), theta / pi, phi / pi, the albedo as log(1 - albedo) / log(1 - ALBEDO_MAX) (the dataset's spacing; albedos
above ALBEDO_MAX are taken at ALBEDO_MAX: the networks never saw them) and (g + 1) / 2.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..bake import mlp

KINDS = ("double", "multiple")
WEIGHTS = Path(__file__).resolve().parents[1] / "bake" / "weights"
ALBEDO_MAX = 0.999

# Encoding version 1: the sinh map of the training grid (training.medium_tracer.sinh_edges) and its extents.
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


def predict(net: mlp.MLP, rho, z, theta, phi, albedo, g) -> np.ndarray:
    """Phi at the given points, directions and materials (flattened broadcast), non-negative."""
    x = encode(rho, z, theta, phi, albedo, g, net.manifest.get("encoding", ENCODING))
    return np.maximum(np.expm1(net(x)[:, 0]), 0.0)


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


def table_energy(phi_table: np.ndarray, rho_edges, z_edges) -> float:
    """Power the table emits, per unit source power: the sum of Phi x cell volume x bin solid angle."""
    r, z = np.asarray(rho_edges, dtype=np.float64), np.asarray(z_edges, dtype=np.float64)
    volumes = np.pi * np.outer(np.diff(r * r), np.diff(z))
    return float(np.einsum("ijkl,ij,kl->", phi_table, volumes, bin_solid_angles(*phi_table.shape[2:])))
