"""Numpy inference of the small MLPs trained in ``training/`` (Blender ships no torch).

A weights file is an .npz with ``w0, b0, w1, b1, ...`` (``w`` of shape (inputs, outputs)) and a JSON
``manifest`` string (training data size, seed, validation errors, code version). Hidden layers use the manifest's
``activation``: SiLU, x·sigmoid(x) (the default: SpongeCake's networks), or tanh (the neural media's, as their
paper); the last layer is linear. Inference runs in float32, the precision the networks are trained and stored in
(twice as fast as float64, and as close to torch), and returns float64.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np


def silu(x):
    return x / (1.0 + np.exp(-np.clip(x, -60.0, 60.0)))


ACTIVATIONS = {"silu": silu, "tanh": np.tanh}


def hidden_widths(weights) -> tuple:
    """The hidden layers' widths of a network with these weights."""
    return tuple(w.shape[1] for w in weights[:-1])


@dataclass(frozen=True)
class MLP:
    weights: tuple
    biases: tuple
    manifest: dict

    def __post_init__(self):
        for name in ("weights", "biases"):
            object.__setattr__(self, name, tuple(np.asarray(a, np.float32) for a in getattr(self, name)))

    @property
    def n_inputs(self) -> int:
        return self.weights[0].shape[0]

    @property
    def hidden(self) -> tuple:
        return hidden_widths(self.weights)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        activation = ACTIVATIONS[self.manifest.get("activation", "silu")]
        h = np.asarray(x, dtype=np.float32)
        for i, (w, b) in enumerate(zip(self.weights, self.biases)):
            h = h @ w + b
            if i + 1 < len(self.weights):
                h = activation(h)
        return h.astype(np.float64)


def save(path, weights, biases, manifest: dict) -> None:
    from .exr import atomic_path

    arrays = {f"w{i}": np.asarray(w, np.float32) for i, w in enumerate(weights)}
    arrays.update({f"b{i}": np.asarray(b, np.float32) for i, b in enumerate(biases)})
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, manifest=np.array(json.dumps(manifest)), **arrays)


@lru_cache(maxsize=8)
def load(path) -> MLP:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"network weights {path} are missing: reinstall Lamina or run training/train.py")
    with np.load(path) as data:
        n = sum(1 for k in data.files if k.startswith("w"))
        weights = tuple(data[f"w{i}"] for i in range(n))
        biases = tuple(data[f"b{i}"] for i in range(n))
        manifest = json.loads(str(data["manifest"]))
    return MLP(weights, biases, manifest)
