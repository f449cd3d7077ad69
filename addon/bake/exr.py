"""Atomic image writers (OpenEXR float, PNG 8-bit) and readers; no bpy.

Every writer first writes a temporary file in the destination folder and then ``os.replace``s it onto
the final name, so a reader never sees a half-written file and a failed write leaves the old file (or
nothing) behind, never a temporary.

Row order: arrays are H x W x C with row 0 at the TOP of the picture, which is the order in which EXR
and PNG store their scanlines. (Blender's ``Image.pixels`` start at the bottom; this module never
goes through Blender.)

The PNG writer is pure Python (zlib + struct) so it works in any interpreter; the EXR functions need
the ``OpenEXR`` package (>= 3.3 API: ``OpenEXR.File``).
"""
from __future__ import annotations

import contextlib
import os
import struct
import tempfile
import zlib

import numpy as np

__all__ = ["atomic_path", "write_exr", "read_exr", "write_png", "read_png"]


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path in ``path``'s folder; on success ``os.replace`` it onto ``path``.

    On an exception the temporary file is removed and the exception propagates; ``path`` is untouched.
    The temporary name keeps ``path``'s extension (some writers look at it).
    """
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    base = os.path.basename(path)
    _, ext = os.path.splitext(base)
    fd, tmp = tempfile.mkstemp(prefix="." + base + ".", suffix=".tmp" + ext, dir=folder)
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the file the permissions open() would
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _as_hwc(image, name="image"):
    a = np.asarray(image)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in (1, 3, 4) or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"{name}: expected an H x W, H x W x 3 or H x W x 4 array, got shape {a.shape}")
    return a


# ----------------------------------------------------------------------------------------------- EXR

def write_exr(path, image, *, compression="ZIP"):
    """Write a float image (H x W, H x W x 3 or H x W x 4; row 0 = top) as a 32-bit float EXR, atomically.

    Channels are named Y, RGB or RGBA. NaN/inf are written as they are (callers decide how to treat them).
    """
    import OpenEXR

    a = _as_hwc(image).astype(np.float32)
    key = {1: "Y", 3: "RGB", 4: "RGBA"}[a.shape[2]]
    data = a[:, :, 0] if key == "Y" else a
    header = {
        "compression": getattr(OpenEXR, f"{compression.upper()}_COMPRESSION"),
        "type": OpenEXR.scanlineimage,
    }
    with atomic_path(path) as tmp:
        with OpenEXR.File(header, {key: np.ascontiguousarray(data)}) as f:
            f.write(tmp)


def read_exr(path, channels=None):
    """Read an EXR as float64 H x W x C, row 0 = top (the file's first scanline).

    ``channels`` None: RGBA if present, else RGB, else Y (H x W x 1), else the first channel group.
    Otherwise a string such as "RGB" picks those (interleaved keys) or a single channel name.
    """
    import OpenEXR

    with OpenEXR.File(os.fspath(path), separate_channels=False) as f:
        chans = f.channels()
        if channels is None:
            for key in ("RGBA", "RGB", "Y"):
                if key in chans:
                    channels = key
                    break
            else:
                channels = next(iter(chans))
        if channels in chans:
            px = np.asarray(chans[channels].pixels)
        elif channels == "RGB" and "RGBA" in chans:
            px = np.asarray(chans["RGBA"].pixels)[:, :, :3]
        else:
            raise KeyError(f"{path}: no channel group {channels!r}; has {sorted(chans)}")
    px = np.array(px, dtype=np.float64)
    if px.ndim == 2:
        px = px[:, :, None]
    return px


# ----------------------------------------------------------------------------------------------- PNG

def _png_chunk(tag: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)


def png_bytes(image) -> bytes:
    """Encode an 8-bit image (H x W, H x W x 3 or H x W x 4 uint8; row 0 = top) as PNG bytes."""
    a = _as_hwc(image)
    if a.dtype != np.uint8:
        raise ValueError(f"PNG: expected uint8 pixels, got {a.dtype} (tone-map first)")
    h, w, c = a.shape
    color_type = {1: 0, 3: 2, 4: 6}[c]
    raw = np.zeros((h, 1 + w * c), dtype=np.uint8)  # filter byte 0 (None) per row
    raw[:, 1:] = a.reshape(h, w * c)
    ihdr = struct.pack(">IIBBBBB", w, h, 8, color_type, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", ihdr)
            + _png_chunk(b"IDAT", zlib.compress(raw.tobytes(), 6)) + _png_chunk(b"IEND", b""))


def write_png(path, image):
    """Write an 8-bit image (uint8, row 0 = top) as PNG, atomically; pure Python."""
    data = png_bytes(image)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)


def read_png(path):
    """Read an 8-bit, non-interlaced grey/RGB/RGBA PNG (any row filter) as uint8 H x W x C."""
    with open(path, "rb") as f:
        data = f.read()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError(f"{path}: not a PNG file")
    pos, idat, ihdr = 8, [], None
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos:pos + 4])
        tag = data[pos + 4:pos + 8]
        body = data[pos + 8:pos + 8 + n]
        pos += 12 + n
        if tag == b"IHDR":
            ihdr = struct.unpack(">IIBBBBB", body)
        elif tag == b"IDAT":
            idat.append(body)
        elif tag == b"IEND":
            break
    if ihdr is None:
        raise ValueError(f"{path}: no IHDR chunk")
    w, h, depth, color_type, _, _, interlace = ihdr
    channels = {0: 1, 2: 3, 4: 2, 6: 4}.get(color_type)
    if depth != 8 or channels is None or interlace:
        raise ValueError(f"{path}: only 8-bit non-interlaced grey/RGB/RGBA PNGs are supported")
    raw = np.frombuffer(zlib.decompress(b"".join(idat)), dtype=np.uint8).reshape(h, 1 + w * channels)
    out = np.zeros((h, w * channels), dtype=np.int32)
    bpp = channels
    prev = np.zeros(w * channels, dtype=np.int32)
    for y in range(h):
        ftype, line = raw[y, 0], raw[y, 1:].astype(np.int32)
        cur = np.zeros_like(line)
        if ftype == 0:
            cur = line
        elif ftype == 2:
            cur = (line + prev) & 255
        else:  # 1 Sub, 3 Average, 4 Paeth depend on the left neighbour: sequential
            for x in range(line.size):
                left = cur[x - bpp] if x >= bpp else 0
                up = prev[x]
                if ftype == 1:
                    p = left
                elif ftype == 3:
                    p = (left + up) >> 1
                elif ftype == 4:
                    ul = prev[x - bpp] if x >= bpp else 0
                    pa, pb, pc = abs(up - ul), abs(left - ul), abs(left + up - 2 * ul)
                    p = left if pa <= pb and pa <= pc else (up if pb <= pc else ul)
                else:
                    raise ValueError(f"{path}: bad PNG filter type {ftype}")
                cur[x] = (line[x] + p) & 255
        out[y] = cur
        prev = cur
    return out.astype(np.uint8).reshape(h, w, channels)
