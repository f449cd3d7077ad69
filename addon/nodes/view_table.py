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
from dataclasses import dataclass, replace

import numpy as np

from .expr import MIN_COS


@dataclass(frozen=True)
class Axis:
    """A table's columns over the value of the shader input ``socket``: ``values`` ascending, uniform in
    log(``sign`` · value + ``offset``), or in the value where ``offset`` is None. For a colour input (``channels``)
    the values are greys and each channel is looked up at its own value."""
    socket: str
    values: tuple
    offset: float | None = None
    sign: float = 1.0
    channels: bool = False

    @classmethod
    def spaced(cls, socket: str, lo: float, hi: float, count: int, offset: float | None = None, sign: float = 1.0,
               channels: bool = False) -> "Axis":
        """``count`` values from ``lo`` to ``hi`` spaced as the axis is (one where they are equal)."""
        axis = cls(socket, (float(lo), float(hi)), offset, sign, channels)
        return replace(axis, values=axis._spaced(count if hi > lo else 1))

    def finer(self, substeps: int) -> tuple:
        """The values with ``substeps`` − 1 more between each two, spaced as they are."""
        return self._spaced((len(self.values) - 1) * substeps + 1)

    def value(self, v: float):
        """What the input holds at the axis value ``v`` (a grey for a colour input)."""
        return (v,) * 3 if self.channels else v

    def to_json(self) -> list:
        return [self.socket, list(self.values), self.offset, self.sign, self.channels]

    @classmethod
    def from_json(cls, data) -> "Axis":
        socket, values, offset, sign, channels = data
        return cls(socket, tuple(float(v) for v in values), offset, float(sign), bool(channels))

    def position(self, x, b=np):
        """Where the input's value ``x`` (a channel's, for a colour input) lies between the first value (0) and the
        last (1), on backend ``b`` (numpy or an ``expr`` backend); 0 where there is one value."""
        if len(self.values) == 1:
            return 0.0
        lo, hi = self._warped(self.values[0], math), self._warped(self.values[-1], math)
        return (self._warped(x, b) - lo) * (1.0 / (hi - lo))

    def _warped(self, x, b):
        return x if self.offset is None else b.log(self.sign * x + self.offset)

    def _spaced(self, count: int) -> tuple:
        lo, hi = self.values[0], self.values[-1]
        if count == 1:
            return (float(lo),)
        warped = np.linspace(self._warped(lo, math), self._warped(hi, math), count)
        inner = warped[1:-1] if self.offset is None else (np.exp(warped[1:-1]) - self.offset) / self.sign
        return tuple(float(v) for v in np.concatenate([[lo], inner, [hi]]))


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
        y = (np.arcsin(np.sqrt(np.minimum(np.maximum(wo[:, 2], MIN_COS), 1.0))) * sy + oy) * self.shape[0] - 0.5
        image = pixels[..., :3].astype(np.float64)
        if self.axis is None:
            along = np.mod(np.arctan2(wo[:, 1], wo[:, 0]), 2.0 * math.pi) / (2.0 * math.pi)
        else:
            value = np.asarray(inputs[self.axis.socket], np.float64)
            along = np.broadcast_to(self.axis.position(value), (len(wo), 3) if self.axis.channels else len(wo))
        x = (along * sx + ox) * pixels.shape[1] - 0.5
        if x.ndim == 1:
            return _bilinear(image, x, y)
        return np.stack([_bilinear(image, x[:, c], y)[:, c] for c in range(3)], axis=1)  # each channel at its value


def _bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    height, width = image.shape[:2]
    ix, iy = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - ix)[:, None], (y - iy)[:, None]
    x0, x1 = np.clip(ix, 0, width - 1), np.clip(ix + 1, 0, width - 1)
    y0, y1 = np.clip(iy, 0, height - 1), np.clip(iy + 1, 0, height - 1)
    return ((1.0 - fy) * ((1.0 - fx) * image[y0, x0] + fx * image[y0, x1])
            + fy * ((1.0 - fx) * image[y1, x0] + fx * image[y1, x1]))
