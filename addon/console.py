"""Blender's own console lines ("Saved: '…tmp.exr'", "Read blend: …", "Library file, loading empty scene")
kept away from a headless user (bpy-free).

Blender writes them from C to the process's file descriptors 1 and 2, below Python's ``sys.stdout``, so
``blender_quiet`` points both descriptors at a scratch file for the duration of a Blender call and back
afterwards. Lamina's own lines are printed outside these calls. ``LAMINA_VERBOSE=1`` shows everything.
"""
from __future__ import annotations

import contextlib
import os
import sys
import tempfile


@contextlib.contextmanager
def blender_quiet():
    """Hide what Blender prints during the ``with`` block (Python's own prints in it are hidden too)."""
    if os.environ.get("LAMINA_VERBOSE") or not _redirectable():
        yield
        return
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    saved = [os.dup(fd) for fd in (1, 2)]
    try:
        with tempfile.TemporaryFile() as scratch:
            for fd in (1, 2):
                os.dup2(scratch.fileno(), fd)
            try:
                yield
            finally:
                for stream in (sys.stdout, sys.stderr):
                    stream.flush()
                for fd, copy in zip((1, 2), saved):
                    os.dup2(copy, fd)
    finally:
        for copy in saved:
            os.close(copy)


def _redirectable() -> bool:
    """Whether descriptors 1 and 2 exist (an embedding host may have closed them)."""
    try:
        os.fstat(1)
        os.fstat(2)
    except OSError:
        return False
    return True
