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
towards N × T, and one column more repeating the first, so the azimuth wraps around. A table of an isotropic material
one of whose inputs a texture drives has an ``Axis`` over that input's value instead of the azimuth: column c at the
c-th of its values, uniform in log(value + offset) (or in the value), looked up at the value the texture feeds the
input, so that the table follows the texels.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

import numpy as np

from .expr import MIN_COS


@dataclass(frozen=True)
class Axis:
    """A table's columns over the value of the shader input ``socket`` (a float): ``values`` ascending, uniform in
    log(value + ``offset``), or in the value where ``offset`` is None."""
    socket: str
    values: tuple
    offset: float | None = None

    @classmethod
    def spaced(cls, socket: str, lo: float, hi: float, count: int, offset: float | None = None) -> "Axis":
        """``count`` values from ``lo`` to ``hi`` uniform in log(value + ``offset``) (or in the value); one where
        they are equal."""
        return cls(socket, _spaced(lo, hi, count if hi > lo else 1, offset), offset)

    def finer(self, substeps: int) -> tuple:
        """The values with ``substeps`` − 1 more between each two, spaced as they are."""
        return _spaced(self.values[0], self.values[-1], (len(self.values) - 1) * substeps + 1, self.offset)

    def to_json(self) -> list:
        return [self.socket, list(self.values), self.offset]

    @classmethod
    def from_json(cls, data) -> "Axis":
        socket, values, offset = data
        return cls(socket, tuple(float(v) for v in values), offset)

    def position(self, x, b=np):
        """Where the input's value ``x`` lies between the first value (0) and the last (1), on backend ``b`` (numpy
        or an ``expr`` backend); 0 where there is one value."""
        if len(self.values) == 1:
            return 0.0
        lo, hi = self._warped(self.values[0], math), self._warped(self.values[-1], math)
        return (self._warped(x, b) - lo) * (1.0 / (hi - lo))

    def _warped(self, x, b):
        return x if self.offset is None else b.log(x + self.offset)


@dataclass(frozen=True, eq=False)
class ViewTable:
    values: np.ndarray  # (rows, columns, 3): columns over the azimuth, or over ``axis``' values
    lowest: float  # asin(√μ) of the first row
    axis: Axis | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return self.values.shape[:2]

    @property
    def name(self) -> str:
        """The image's name: the table's content hash (tables with the same values share one image)."""
        axis = repr(self.axis.to_json()).encode() if self.axis else b""
        digest = hashlib.md5(self.pixels().tobytes() + np.float64(self.lowest).tobytes() + axis).hexdigest()[:12]
        return f"Lamina view table {digest}"

    def pixels(self) -> np.ndarray:
        """RGBA float32 (rows, image columns, 4), bottom row first: the image as Blender stores it (over the azimuth,
        one column more repeating the first)."""
        rows, columns = self.shape
        wraps = self.axis is None
        out = np.ones((rows, columns + wraps, 4), dtype=np.float32)
        out[:, :columns, :3] = self.values
        out[:, columns:, :3] = self.values[:, :1]
        return out

    def texel_coordinates(self):
        """(scale, offset) of the image's x and y coordinates: x = (azimuth / 2π, or ``Axis.position``) · scale +
        offset and y = asin(√μ) · scale + offset place each value at its texel's centre (Cycles reads texel i at
        (i + ½) / width)."""
        rows, columns = self.shape
        width = self.pixels().shape[1]
        x = ((columns - (self.axis is not None)) / width, 0.5 / width)
        per_row = (rows - 1) / (0.5 * math.pi - self.lowest)
        y = (per_row / rows, (0.5 - self.lowest * per_row) / rows)
        return x, y

    def at(self, wo: np.ndarray, inputs: dict | None = None) -> np.ndarray:
        """The table at the views ``wo`` (N, 3) in the shading frame, (N, 3), with the inputs' values ``inputs``
        (socket name → value; for an ``axis``): Cycles' bilinear lookup (texel coordinate x · width − ½, neighbours
        clamped at the edges)."""
        (sx, ox), (sy, oy) = self.texel_coordinates()
        pixels = self.pixels()
        if self.axis is None:
            along = np.mod(np.arctan2(wo[:, 1], wo[:, 0]), 2.0 * math.pi) / (2.0 * math.pi)
        else:
            along = np.broadcast_to(self.axis.position(np.asarray(inputs[self.axis.socket], np.float64)), len(wo))
        x = (along * sx + ox) * pixels.shape[1] - 0.5
        y = (np.arcsin(np.sqrt(np.minimum(np.maximum(wo[:, 2], MIN_COS), 1.0))) * sy + oy) * self.shape[0] - 0.5
        return _bilinear(pixels[..., :3].astype(np.float64), x, y)


def _spaced(lo: float, hi: float, count: int, offset: float | None) -> tuple:
    if count == 1:
        return (float(lo),)
    if offset is None:
        return tuple(float(v) for v in np.linspace(lo, hi, count))
    warped = np.linspace(math.log(lo + offset), math.log(hi + offset), count)
    return tuple(float(v) for v in np.concatenate([[lo], np.exp(warped[1:-1]) - offset, [hi]]))


def _bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    height, width = image.shape[:2]
    ix, iy = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - ix)[:, None], (y - iy)[:, None]
    x0, x1 = np.clip(ix, 0, width - 1), np.clip(ix + 1, 0, width - 1)
    y0, y1 = np.clip(iy, 0, height - 1), np.clip(iy + 1, 0, height - 1)
    return ((1.0 - fy) * ((1.0 - fx) * image[y0, x0] + fx * image[y0, x1])
            + fy * ((1.0 - fx) * image[y1, x0] + fx * image[y1, x1]))
