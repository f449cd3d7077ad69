"""SpongeCake layers as flat float rows, the form the dataset stores and the network reads (no bpy, no torch).

A row holds, in this order: type index (0 surface, 1 fiber, 2 hg), roughness (α, or g for hg), albedo RGB,
optical thickness Tρ, f0 RGB, orientation xyz. Stacks are (N, layers, ROW) arrays.
"""
from __future__ import annotations

import numpy as np

from ..models import spongecake as model

ROW = 12
TYPE, ROUGHNESS, ALBEDO, THICKNESS, F0, ORIENTATION = 0, 1, slice(2, 5), 5, slice(6, 9), slice(9, 12)


def layer_row(layer: model.Layer) -> np.ndarray:
    return np.array([model.LAYER_TYPES.index(layer.type), layer.roughness, *layer.albedo, layer.thickness,
                     *layer.f0, *layer.orientation], dtype=np.float64)


def stack_rows(params: model.Params) -> np.ndarray:
    """(layers, ROW) rows of a parameter set, top layer first."""
    return np.stack([layer_row(layer) for layer in params.layers])


def layer_from_row(row) -> model.Layer:
    row = np.asarray(row, dtype=np.float64)
    return model.Layer(type=model.LAYER_TYPES[int(round(row[TYPE]))], roughness=float(row[ROUGHNESS]),
                       albedo=tuple(map(float, row[ALBEDO])), thickness=float(row[THICKNESS]),
                       f0=tuple(map(float, row[F0])), orientation=tuple(map(float, row[ORIENTATION])))


def params_from_rows(rows, substrate=None, delta_transmission=False) -> model.Params:
    return model.Params(tuple(layer_from_row(r) for r in np.atleast_2d(rows)), substrate, delta_transmission)


def flipped(rows) -> np.ndarray:
    """The stack seen from below: layers in reverse order, orientations mirrored through the tangent plane."""
    out = np.array(rows[..., ::-1, :], dtype=np.float64)
    out[..., ORIENTATION.stop - 1] *= -1.0
    return out
