"""Checks of the files and folders a command is given, made before any work (bpy-free).

Each check returns the absolute path or raises ``PathError`` with one line that names the option and the value
as the user typed them. A result folder is filled in a hidden sibling first and moved into place only when the
work succeeded (``staged_folder``), so a failed run leaves the old results (or nothing) behind.
"""
from __future__ import annotations

import contextlib
import os
import shutil
import tempfile

# A .blend starts with "BLENDER"; Blender also saves them compressed (gzip before 3.0, zstd since).
BLEND_MAGICS = (b"BLENDER", b"\x1f\x8b", b"\x28\xb5\x2f\xfd")


class PathError(ValueError):
    """A path argument that cannot be used (a one-line reason naming the option and the value)."""


def _named(option: str, value: str) -> str:
    return f"{option} {value!r}"


def _absolute(option: str, value: str) -> str:
    if value is None or not value.strip():
        raise PathError(f"{option} is empty; give a path")
    return os.path.abspath(os.path.expanduser(value))


def _check_writable_folder(option: str, value: str, folder: str) -> None:
    """The folder that will receive a new entry exists, is a folder, and accepts a file (a probe, removed)."""
    if not os.path.exists(folder):
        raise PathError(f"{_named(option, value)}: the folder {folder} does not exist")
    if not os.path.isdir(folder):
        raise PathError(f"{_named(option, value)}: {folder} is a file, not a folder")
    try:
        fd, probe = tempfile.mkstemp(prefix=".lamina-probe.", dir=folder)
    except OSError as e:
        raise PathError(f"{_named(option, value)}: cannot write in {folder} ({e.strerror or e})") from None
    os.close(fd)
    os.remove(probe)


def output_file(option: str, value: str, overwrite: bool, suffix: str = ".blend") -> str:
    """A file to write: a name ending in ``suffix`` in an existing, writable folder; an existing file only with
    ``overwrite``."""
    path = _absolute(option, value)
    if value.endswith(os.sep) or os.path.isdir(path):
        raise PathError(f"{_named(option, value)} is a folder; expected a {suffix} file")
    if not path.lower().endswith(suffix):
        raise PathError(f"{_named(option, value)}: expected a file name ending in {suffix}")
    _check_writable_folder(option, value, os.path.dirname(path))
    if os.path.exists(path) and not overwrite:
        raise PathError(f"{_named(option, value)} exists; pass --overwrite to replace it")
    return path


def output_folder(option: str, value: str, overwrite: bool) -> str:
    """A result folder: new (its parent exists and is writable), empty, or replaced with ``overwrite``."""
    path = _absolute(option, value)
    if os.path.exists(path) and not os.path.isdir(path):
        raise PathError(f"{_named(option, value)} is a file; expected a folder for the results")
    _check_writable_folder(option, value, os.path.dirname(path))
    if os.path.isdir(path) and os.listdir(path) and not overwrite:
        raise PathError(f"{_named(option, value)} exists and is not empty; pass --overwrite to replace its contents")
    return path


def input_file(option: str, value: str) -> str:
    """A file to read: it exists, is a file and can be opened."""
    path = _absolute(option, value)
    if not os.path.exists(path):
        raise PathError(f"{_named(option, value)} does not exist")
    if os.path.isdir(path):
        raise PathError(f"{_named(option, value)} is a folder; expected a file")
    try:
        with open(path, "rb"):
            pass
    except OSError as e:
        raise PathError(f"{_named(option, value)}: cannot read it ({e.strerror or e})") from None
    return path


def input_blend(option: str, value: str) -> str:
    """A .blend to open: ``input_file`` whose first bytes are a .blend's (plain or compressed)."""
    path = input_file(option, value)
    with open(path, "rb") as f:
        head = f.read(8)
    if not head.startswith(BLEND_MAGICS):
        raise PathError(f"{_named(option, value)} is not a .blend file")
    return path


@contextlib.contextmanager
def staged_folder(path: str):
    """Yield a hidden sibling of ``path`` to fill; on success it replaces ``path`` (whose old contents are
    removed), on failure it is removed and ``path`` is untouched."""
    parent, name = os.path.split(path)
    stage = tempfile.mkdtemp(prefix=f".{name}.", suffix=".lamina-tmp", dir=parent)
    os.chmod(stage, 0o777 & ~_umask())  # mkdtemp makes 0700; give the folder the permissions mkdir would
    try:
        yield stage
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    old = None
    if os.path.exists(path):
        old = tempfile.mkdtemp(prefix=f".{name}.", suffix=".lamina-old", dir=parent)
        os.replace(path, os.path.join(old, name))
    os.replace(stage, path)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def unstaged(text: str, stage: str, path: str) -> str:
    """``text`` (an error message) with the staging folder's name replaced by the final one."""
    return text.replace(stage, path)
