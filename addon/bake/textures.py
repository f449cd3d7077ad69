"""Texture-driven SpongeCake layers: per-texel multiple-scattering bake into RGBA EXR maps (no bpy).

When Image Textures drive a layer's albedo, roughness, thickness or orientation, the network's prediction
(``bake.spongecake.predict_rows``) differs per texel, so the ``MS`` inputs of the generated shader are fed by
baked textures instead of constants. ``bake_maps`` builds one layer-row set per texel (a texture value
overrides that layer's parameter), validates it, runs the network in chunks and packs the ``MS`` socket
values into RGBA maps; ``write_maps`` writes them as EXRs under a content-hash name (``cache_key``), so
baking an unchanged input again finds the files and neither recomputes nor rewrites them.

Inputs: ``{(layer index, parameter name): array}`` with parameter names from ``models.spongecake.LAYER``
whose ``texturable`` flag is set. All arrays share one H x W (row 0 = TOP, as in ``bake.exr``); floats
(roughness, thickness) are H x W, albedo H x W x 3 (or H x W grey), orientation H x W x 3 *raw vectors*:
exactly what Cycles feeds the socket when a texture's Color output is linked to a vector input (no
normal-map remapping: a colour (0.5, 0.5, 1) is the direction of (0.5, 0.5, 1), normalised, as in the shader;
use a float EXR for negative components). Values are in linear (scene-referred) units; ``srgb_to_linear``,
``luminance`` and ``resample`` do what Cycles does to an image before it reaches a socket.
Validation: a NaN or infinite texel is refused (``BakeError`` naming the texture and the count of bad
texels); a value outside the parameter's range is clamped like ``models.spongecake.validate`` does, with one
warning per texture (count of clamped texels) appended to ``warnings``; a zero orientation becomes (0, 0, 1).

EXR layout (RGBA float32, Non-Color, alpha channel-packed: RGB and A are independent data, row 0 = top, the
inputs' H x W; unused channels hold 0, an unused A holds 1). ``map_layout`` derives it from the shader's baked
``MS`` sockets (``nodes.spongecake.sockets``): per layer in declaration order, the i-th colour/vector socket
fills RGB and the i-th float socket A of one map; floats left over fill R, G, B, A of further maps; then the
same for the weights (the Lambert weights and the forward lobe). A map is named after its sockets. With the current
declarations (``k`` the 1-based layer number; RGB weights W2r, W2t):

==================================  ==========================================  ================================
map                                 RGB                                         A
==================================  ==========================================  ================================
``MS Lk Albedo Roughness``          MS Lk Albedo (W1 folded in: may exceed 1)   MS Lk Roughness
``MS Lk F0 Thickness`` (Fresnel)    MS Lk F0                                    MS Lk Thickness
``MS Lk Orientation`` (Fresnel)     MS Lk Orientation                           1 (unused)
``MS Lk Orientation Thickness``     MS Lk Orientation (flakes, no Fresnel)      MS Lk Thickness
``MS Lk Albedo Mean Cosine g``      MS Lk Albedo (hg layers)                    MS Lk Mean Cosine g
``MS Lk Thickness`` (hg layers)     R = MS Lk Thickness, G = B = 0              1 (unused)
``MS Reflection Forward Mean         W2r                                         MS Forward Mean Cosine g
Cosine g``
``MS Transmission Forward           W2t                                         MS Forward Thickness
Thickness`` (no substrate)
``MS Forward Albedo`` (no           the forward lobe's albedo                   1 (unused)
substrate)
``MS Forward Albedo Forward         the forward lobe's albedo (over a           MS Forward Thickness
Thickness`` (over a substrate)      substrate)
==================================  ==========================================  ================================

Orientations are unit tangent-space xyz stored raw (components may be negative), as the shader reads them.
A map's file is ``<folder>/lamina_ms_<key>_<map name, spaces as underscores>.exr``.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
from dataclasses import asdict

import numpy as np

from ..models import spongecake as model
from ..nodes import spongecake as mapping
from . import layer_rows as rows_
from .exr import atomic_path, write_exr
from .spongecake import NETWORK_LAYERS, cycles_weights, predict_rows, weights_path

CHUNK = 65536  # texels per network call: about 0.2 to 0.6 s, the step between progress updates
FORMAT_VERSION = 1  # part of the cache key: bump when the maps' content or layout changes
FIELDS = {"roughness": rows_.ROUGHNESS, "albedo": rows_.ALBEDO, "thickness": rows_.THICKNESS, "f0": rows_.F0,
          "orientation": rows_.ORIENTATION}  # layer parameter → its place in a layer row
LUMINANCE = (0.2126, 0.7152, 0.0722)  # Rec.709: Cycles' colour → float conversion in Blender's default config


class BakeError(ValueError):
    """A bake that cannot be done as asked, with a one-line reason for the user (nothing was written)."""


class Cancelled(Exception):
    """The caller's ``cancel`` callback asked to stop; nothing was written."""


# ------------------------------------------------------------------------------------------ structure

def texturable_inputs(p: model.Params) -> dict:
    """(layer index, parameter name) → the generated shader's socket name, for every texturable layer input."""
    return {(s.layer, s.param.name): s.name for s in mapping.sockets(p)
            if not s.baked and s.layer is not None and s.param.texturable}


def map_layout(p: model.Params) -> dict:
    """Map name → for each of its four channels (R, G, B, A) ``(MS socket name, component)`` or None.

    Per layer (then for the Lambert weights), in declaration order: the i-th colour or vector socket fills
    RGB of a map and the i-th float socket its A; floats left over fill R, G, B, A of further maps. A map is
    named after its sockets, e.g. ``MS L1 Albedo Roughness``."""
    if not p.multiple_scattering:
        raise BakeError("multiple scattering is off: there is nothing to bake")
    groups = {}
    for s in mapping.sockets(p):
        if s.per_texel:
            groups.setdefault(s.layer, []).append(s)
    layout = {}
    for layer, group in groups.items():
        prefix = mapping.MS_PREFIX + ("" if layer is None else f"L{layer + 1} ")
        triples = [s for s in group if s.kind != "float"]
        floats = [s for s in group if s.kind == "float"]
        for s, partner in zip(triples, floats + [None] * len(triples)):
            members = [s] if partner is None else [s, partner]
            layout[prefix + " ".join(m.name[len(prefix):] for m in members)] = (
                tuple((s.name, c) for c in range(3)) + (None if partner is None else (partner.name, 0),))
        rest = floats[len(triples):]
        for i in range(0, len(rest), 4):
            members = rest[i:i + 4]
            layout[prefix + " ".join(m.name[len(prefix):] for m in members)] = (
                tuple((m.name, 0) for m in members) + (None,) * (4 - len(members)))
    return layout


def _weight_columns() -> dict:
    """MS weight parameter name → its columns in ``predict_rows``' weights (declaration order, RGB or scalar)."""
    out, start = {}, 0
    for prm in mapping.MS_WEIGHTS:
        width = 1 if prm.kind == "float" else 3
        out[prm.name] = slice(start, start + width)
        start += width
    return out


# ------------------------------------------------------------------------------- colour and resampling

def srgb_to_linear(x):
    """The sRGB transfer function (IEC 61966-2-1), what Cycles applies to 8-bit sRGB textures."""
    x = np.asarray(x, dtype=np.float32)
    return np.where(x <= 0.04045, x / 12.92, ((np.maximum(x, 0.04045) + 0.055) / 1.055) ** 2.4).astype(np.float32)


def luminance(rgb):
    """H x W x 3 → H x W: what Cycles feeds a float socket linked to a colour output."""
    return np.asarray(rgb, dtype=np.float32) @ np.asarray(LUMINANCE, dtype=np.float32)


def resample(image, size, nearest=False):
    """``image`` (H x W or H x W x C, row 0 = top) sampled at the texel centres of ``size`` = (height, width):
    bilinear (or nearest, for textures shown with Closest interpolation), edges clamped."""
    a = np.asarray(image)
    h, w = a.shape[:2]
    if (h, w) == tuple(size):
        return a

    def coords(n_out, n_in):
        x = np.clip((np.arange(n_out) + 0.5) * n_in / n_out - 0.5, 0.0, n_in - 1)
        if nearest:
            i = np.minimum(np.floor(x + 0.5), n_in - 1).astype(int)
            return i, i, np.zeros(n_out)
        i0 = np.floor(x).astype(int)
        return i0, np.minimum(i0 + 1, n_in - 1), x - i0

    y0, y1, fy = coords(size[0], h)
    x0, x1, fx = coords(size[1], w)
    fy = fy.reshape(-1, 1, *([1] * (a.ndim - 2)))
    fx = fx.reshape(1, -1, *([1] * (a.ndim - 2)))
    top = a[y0][:, x0] * (1 - fx) + a[y0][:, x1] * fx
    bottom = a[y1][:, x0] * (1 - fx) + a[y1][:, x1] * fx
    return (top * (1 - fy) + bottom * fy).astype(a.dtype)


# ---------------------------------------------------------------------------------------------- rows

def _label(key, labels):
    return (labels or {}).get(key) or f"the L{key[0] + 1} {key[1]} texture"


def _range(layer: model.Layer, name: str):
    if name == "roughness":
        return (model.MIN_FLAKE_ROUGHNESS, 1.0) if layer.is_flake else (-model.MAX_ABS_G, model.MAX_ABS_G)
    prm = next(q for q in model.LAYER if q.name == name)
    return prm.min, prm.max


def input_ranges(p: model.Params, inputs: dict) -> dict:
    """(layer index, parameter name) → (least, greatest) of each float or colour input's finite texels (over the
    channels of a colour), clamped to the parameter's range as the bake clamps them (``nodes.spongecake.
    texel_energy``'s axis spans them); None for a direction."""
    out = {}
    for (k, name), value in inputs.items():
        a = np.asarray(value, dtype=np.float64)
        if next(q.kind for q in model.LAYER if q.name == name) != "vector" and np.isfinite(a).any():
            a = np.clip(a[np.isfinite(a)], *_range(p.layers[k], name))
            out[k, name] = (float(a.min()), float(a.max()))
        else:
            out[k, name] = None
    return out


def _texel_values(p, key, value, size, label, warnings) -> np.ndarray:
    """One texture as (H * W, components) float64 values of its parameter, checked and clamped."""
    k, name = key
    kind = next(q.kind for q in model.LAYER if q.name == name)
    a = np.asarray(value, dtype=np.float64)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if kind == "color" and a.ndim == 2:
        a = np.repeat(a[:, :, None], 3, axis=2)
    want = 2 if kind == "float" else 3
    if a.ndim != want or a.shape[:2] != size or (want == 3 and a.shape[2] != 3):
        form = "H x W" if kind == "float" else "H x W x 3"
        raise BakeError(f"{label}: expected {form} values of size {size[0]} x {size[1]}, got shape {a.shape}")
    a = a.reshape(size[0] * size[1], -1)
    bad = int(np.count_nonzero(~np.isfinite(a).all(axis=1)))
    if bad:
        raise BakeError(f"{label}: {bad} texel(s) are NaN or infinite; fix the image before baking")
    layer = p.layers[k]
    if kind == "vector":
        length = np.linalg.norm(a, axis=1, keepdims=True)
        zero = length[:, 0] < 1e-12
        if zero.any():
            warnings.append(f"{label}: {int(zero.sum())} texel(s) have no direction, using (0, 0, 1)")
        return np.where(zero[:, None], np.array([0.0, 0.0, 1.0]), a / np.maximum(length, 1e-12))
    lo, hi = _range(layer, name)
    clamped = np.clip(a, lo, hi)
    outside = int(np.count_nonzero((clamped != a).any(axis=1)))
    if outside:
        warnings.append(f"{label}: {outside} of {len(a)} texel(s) outside [{lo:g}, {hi:g}] for {layer.type} "
                        f"layers, clamped")
    return clamped


def texel_rows(p: model.Params, inputs: dict, labels=None, warnings=None):
    """Per-texel layer rows (H * W, layers, ROW) and the common size (H, W); see the module docstring."""
    if not inputs:
        raise BakeError("no texture drives a layer input: nothing to bake (the constant MS values apply)")
    allowed = texturable_inputs(p)
    unknown = [key for key in inputs if key not in allowed]
    if unknown:
        raise BakeError(f"not texturable here: {', '.join(f'layer {k + 1} {n}' for k, n in unknown)}; "
                        f"expected some of {', '.join(allowed.values())}")
    sizes = {key: np.shape(v)[:2] for key, v in inputs.items()}
    size = next(iter(sizes.values()))
    if any(s != size for s in sizes.values()) or min(size, default=0) < 1:
        raise BakeError(f"textures must share one size (resample them first), got "
                        f"{', '.join(f'{_label(k, labels)} {s}' for k, s in sizes.items())}")
    warnings = [] if warnings is None else warnings
    rows = np.repeat(rows_.stack_rows(p)[None], size[0] * size[1], axis=0)
    for key in sorted(inputs):
        values = _texel_values(p, key, inputs[key], size, _label(key, labels), warnings)
        field = FIELDS[key[1]]
        rows[:, key[0], field] = values if isinstance(field, slice) else values[:, 0]
    return rows, size


# ---------------------------------------------------------------------------------------------- bake

def synthetic_inputs(p: model.Params, size: int, seed: int = 0) -> dict:
    """Every texturable layer input of ``p`` driven by a random size x size texture around the layer's value,
    inside the parameter ranges (benchmarks time ``bake_maps`` on these without Blender)."""
    rng = np.random.default_rng(seed)
    inputs = {}
    for k, name in texturable_inputs(p):
        value = np.asarray(getattr(p.layers[k], name), dtype=np.float64)
        if name == "albedo":
            inputs[k, name] = rng.uniform(0.2, 0.9, (size, size, 3))
        elif name == "orientation":
            inputs[k, name] = value + 0.2 * rng.standard_normal((size, size, 3))
        else:
            inputs[k, name] = np.clip(value * rng.uniform(0.5, 1.0, (size, size)), *_range(p.layers[k], name))
    return inputs


def bake_steps(p: model.Params, inputs: dict, labels=None, warnings=None, chunk: int = CHUNK):
    """A generator: validates (on the first ``next``), then runs the network one chunk per step, yielding
    the fraction done; its return value (``StopIteration.value``) is ``{map name: H x W x 4 float32}``."""
    layout = map_layout(p)
    rows, (h, w) = texel_rows(p, inputs, labels, warnings)
    n = len(rows)
    lobes = np.empty_like(rows)
    weights = np.empty((n, max(c.stop for c in _weight_columns().values())))
    for start in range(0, n, chunk):
        stop = min(start + chunk, n)
        lobes[start:stop], decoded = predict_rows(rows[start:stop])
        weights[start:stop] = cycles_weights(rows[start:stop], decoded)
        yield stop / n
    return pack_maps(p, layout, lobes, weights, (h, w))


def bake_maps(p: model.Params, inputs: dict, progress=None, cancel=None, labels=None, warnings=None,
              chunk: int = CHUNK) -> dict:
    """{map name: H x W x 4 float32} for texture-driven layers (module docstring: inputs, checks, layout).

    ``progress(fraction)`` is called after each chunk; ``cancel()`` is checked before each chunk and, when
    true, raises ``Cancelled``. ``labels`` names the textures in messages ({input key: text});
    clamping messages are appended to ``warnings``. Raises ``BakeError`` for refused inputs."""
    steps = bake_steps(p, inputs, labels, warnings, chunk)
    while True:
        if cancel is not None and cancel():
            steps.close()
            raise Cancelled("baking cancelled: nothing was written")
        try:
            fraction = next(steps)
        except StopIteration as done:
            return done.value
        if progress is not None:
            progress(fraction)


def pack_maps(p: model.Params, layout: dict, lobes: np.ndarray, weights: np.ndarray, size) -> dict:
    """Network outputs per texel → the RGBA maps of ``layout`` (unused channels: RGB 0, A 1)."""
    n = len(lobes)
    columns = _weight_columns()
    values = {s.name: (weights[:, columns[s.param.name]] if s.layer is None
                       else lobes[:, s.layer, FIELDS[s.param.name]]).reshape(n, -1)
              for s in mapping.sockets(p) if s.per_texel}
    maps = {}
    for name, channels in layout.items():
        out = np.zeros((n, 4), dtype=np.float32)
        out[:, 3] = 1.0
        for c, entry in enumerate(channels):
            if entry is not None:
                out[:, c] = values[entry[0]][:, entry[1]]
        maps[name] = out.reshape(size[0], size[1], 4)
    return maps


# --------------------------------------------------------------------------------------------- cache

def cache_key(p: model.Params, inputs: dict) -> str:
    """Content hash of what the maps depend on: the layers, whether a substrate closes the stack, every
    input texture's values and the network weights file."""
    h = hashlib.sha256()
    h.update(json.dumps({"version": FORMAT_VERSION, "layers": [asdict(layer) for layer in p.layers],
                         "substrate": p.substrate is not None}, sort_keys=True).encode())
    for key in sorted(inputs):
        a = np.ascontiguousarray(inputs[key])
        h.update(repr((key, a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    h.update(weights_path(min(len(p.layers), NETWORK_LAYERS)).read_bytes())  # deeper stacks: the two-layer one
    return h.hexdigest()[:24]


def map_paths(names, folder, key: str) -> dict:
    return {name: os.path.join(os.fspath(folder), f"lamina_ms_{key}_{name.replace(' ', '_')}.exr")
            for name in names}


def cached_maps(p: model.Params, folder, key: str) -> dict | None:
    """The map files of an earlier bake of the same content, or None when any is missing."""
    paths = map_paths(map_layout(p), folder, key)
    return paths if all(os.path.isfile(path) for path in paths.values()) else None


def write_maps(maps: dict, folder, key: str) -> dict:
    """Write every map as an RGBA float EXR in ``folder``; {map name: path}. All or nothing: every file is
    written to a temporary first and the set is renamed into place only when all succeeded. A complete
    set already there (same key, so same content) is a cache hit: nothing is rewritten."""
    paths = map_paths(maps, folder, key)
    if all(os.path.isfile(path) for path in paths.values()):
        return paths
    with contextlib.ExitStack() as stack:
        temporaries = {name: stack.enter_context(atomic_path(path)) for name, path in paths.items()}
        for name, tmp in temporaries.items():
            write_exr(tmp, maps[name])
    return paths
