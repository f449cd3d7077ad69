"""The asset library's catalogs and previews, without Blender (the library itself: ``operators/asset_library.py``).

Every BSDF model (a model with a Cycles mapping, ``nodes.MAPPINGS``) gets the catalog ``Lamina/<model label>``; its
UUID is derived from the model id (UUID 5), so that rebuilding the library keeps the catalogs Blender already knows.
The catalog file is Blender's ``blender_assets.cats.txt`` (version 1: ``UUID:path:simple name`` per line).
"""
from __future__ import annotations

import uuid

import numpy as np

LIBRARY_FILE = "lamina_library.blend"
CATALOG_FILE = "blender_assets.cats.txt"
LIBRARY_NAME = "Lamina"  # the user asset-library entry
PREVIEW_SIZE = 128  # pixels of an asset's rendered preview (square)
PREVIEW_SAMPLES = 32
_NAMESPACE = uuid.UUID("6f1d0c52-6a55-4b8e-9a43-6c616d696e61")


def catalog_id(model_id: str) -> str:
    return str(uuid.uuid5(_NAMESPACE, model_id))


def catalog_path(label: str) -> str:
    return f"{LIBRARY_NAME}/{label}"


def catalog_text(labels: dict) -> str:
    """The catalog file for ``labels`` ({model id: label}), in the given order."""
    lines = ["# Asset catalogs of the Lamina asset library (written by Lamina; rebuilt with the library).",
             "VERSION 1", ""]
    lines += [f"{catalog_id(m)}:{catalog_path(label)}:{LIBRARY_NAME}-{label.replace(' ', '-')}"
              for m, label in labels.items()]
    return "\n".join(lines) + "\n"


def preview_pixels(image: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """A rendered image (H x W x 3 linear, row 0 at the top) as an ID preview's flat RGBA floats: sRGB-encoded and
    clamped to [0, 1], transparent outside ``mask``, rows from the bottom (Blender's image order)."""
    x = np.clip(np.asarray(image, dtype=np.float64), 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    rgba = np.dstack([srgb, np.asarray(mask, dtype=np.float64)])
    return rgba[::-1].astype(np.float32).ravel()
