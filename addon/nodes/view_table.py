"""Values that follow the view direction, tabulated over its elevation and azimuth and looked up the way Cycles looks
up a small float image (Image Texture node, Linear interpolation, Extend): bilinear between texel centres.

A closure weight in a node group or OSL shader can follow the view's angle from the normal through math on the
Geometry node, but a measured table over it (SpongeCake's multiple-scattering energy budget), and over the azimuth as
well for an oriented stack, is one texture lookup of a per-material image (one azimuth column where the table has
no azimuth): ``view_wiring`` feeds a Lamina node's inputs from one, and ``NumpyBackend.input`` evaluates a
``ViewTable`` at its views with ``at``, so the numpy prediction renders what Cycles renders.

The texel grid: row r (image row r from the bottom) at asin(√μ) = lowest + (π/2 − lowest) r / (rows − 1), μ the view's
cosine with the shading normal (at least ``expr.MIN_COS``, as the closures' own): rows uniform in the view's angle
near the normal and in √μ near grazing; column c at azimuth 2π c / azimuths from the Geometry node's tangent T
towards N × T, and one column more repeating the first, so the azimuth wraps around.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

import numpy as np

from .expr import MIN_COS


@dataclass(frozen=True, eq=False)
class ViewTable:
    values: np.ndarray  # (rows, azimuths, 3)
    lowest: float  # asin(√μ) of the first row

    @property
    def shape(self) -> tuple[int, int]:
        return self.values.shape[:2]

    @property
    def name(self) -> str:
        """The image's name: the table's content hash (tables with the same values share one image)."""
        digest = hashlib.md5(self.pixels().tobytes() + np.float64(self.lowest).tobytes()).hexdigest()[:12]
        return f"Lamina view table {digest}"

    def pixels(self) -> np.ndarray:
        """RGBA float32 (rows, azimuths + 1, 4), bottom row first: the image as Blender stores it."""
        rows, azimuths = self.shape
        out = np.ones((rows, azimuths + 1, 4), dtype=np.float32)
        out[:, :azimuths, :3] = self.values
        out[:, azimuths, :3] = self.values[:, 0]
        return out

    def texel_coordinates(self):
        """(scale, offset) of the image's x and y coordinates: x = azimuth / 2π · scale + offset and
        y = asin(√μ) · scale + offset place each value at its texel's centre (Cycles reads texel i at (i + ½) / width)."""
        rows, azimuths = self.shape
        x = (azimuths / (azimuths + 1.0), 0.5 / (azimuths + 1.0))
        per_row = (rows - 1) / (0.5 * math.pi - self.lowest)
        y = (per_row / rows, (0.5 - self.lowest * per_row) / rows)
        return x, y

    def at(self, wo: np.ndarray) -> np.ndarray:
        """The table at the views ``wo`` (N, 3) in the shading frame, (N, 3): Cycles' bilinear lookup (texel
        coordinate x · width − ½, neighbours clamped at the edges)."""
        (sx, ox), (sy, oy) = self.texel_coordinates()
        turn = np.mod(np.arctan2(wo[:, 1], wo[:, 0]), 2.0 * math.pi) / (2.0 * math.pi)
        x = (turn * sx + ox) * (self.shape[1] + 1) - 0.5
        y = (np.arcsin(np.sqrt(np.minimum(np.maximum(wo[:, 2], MIN_COS), 1.0))) * sy + oy) * self.shape[0] - 0.5
        return _bilinear(self.pixels()[..., :3].astype(np.float64), x, y)


def _bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    height, width = image.shape[:2]
    ix, iy = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - ix)[:, None], (y - iy)[:, None]
    x0, x1 = np.clip(ix, 0, width - 1), np.clip(ix + 1, 0, width - 1)
    y0, y1 = np.clip(iy, 0, height - 1), np.clip(iy + 1, 0, height - 1)
    return ((1.0 - fy) * ((1.0 - fx) * image[y0, x0] + fx * image[y0, x1])
            + fy * ((1.0 - fx) * image[y1, x0] + fx * image[y1, x1]))
