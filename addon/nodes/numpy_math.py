"""The float64 math of ``expr.NumpyBackend`` (stateless), also used where a formula written for the expression
backends is evaluated in numpy outside a backend (``closures_np``)."""
from __future__ import annotations

import numpy as np

# Smallest argument of a logarithm (float32-safe: its log is finite).
MIN_LOG = 1e-30


class NumpyMath:
    exp = staticmethod(np.exp)
    log = staticmethod(lambda x: np.log(np.maximum(x, MIN_LOG)))
    sqrt = staticmethod(lambda x: np.sqrt(np.maximum(x, 0.0)))
    maximum = staticmethod(np.maximum)
    minimum = staticmethod(np.minimum)
    abs = staticmethod(np.abs)
    cos = staticmethod(np.cos)
    sin = staticmethod(np.sin)
    atan2 = staticmethod(np.arctan2)  # atan2(y, x)
    acos = staticmethod(lambda x: np.arccos(np.clip(x, -1.0, 1.0)))

    @staticmethod
    def multiply_add(a, s, c):
        """a · s + c: a and c both floats or both colours, s a float."""
        a, s = np.asarray(a), np.asarray(s)
        return a * (s[..., None] if a.shape[-1:] == (3,) and s.shape[-1:] != (3,) else s) + np.asarray(c)

    @staticmethod
    def channel(color, i: int):
        return np.asarray(color)[..., i]

    @staticmethod
    def channel_mean(color):
        return np.mean(color, axis=-1)

    @staticmethod
    def step_below(x, edge):
        return np.where(x < edge, 1.0, 0.0)
