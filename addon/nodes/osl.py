"""Compile generated OSL with Cycles' own compiler and load it into a script node as INTERNAL bytecode.

The PyPI bpy module has no ``oslquery`` (research notes §6), so sockets are created from the .oso's
``param`` lines. Bytecode stored INTERNAL is saved in the .blend: the file renders without Lamina.
"""
from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass

SOCKET_TYPES = {"float": "NodeSocketFloat", "color": "NodeSocketColor", "vector": "NodeSocketVector",
                "point": "NodeSocketVector", "normal": "NodeSocketVector", "int": "NodeSocketInt",
                "string": "NodeSocketString", "closure color": "NodeSocketShader"}


class OslCompileError(RuntimeError):
    pass


@dataclass(frozen=True)
class OsoParam:
    name: str
    type: str
    output: bool
    default: tuple


def compile_source(source: str) -> str:
    """OSL source → .oso text, via ``_cycles.osl_compile``; cached on the source's hash for this process."""
    key = hashlib.md5(source.encode()).hexdigest()
    if key not in _CACHE:
        _CACHE[key] = _compile(source)
    return _CACHE[key]


_CACHE: dict[str, str] = {}


def _compile(source: str) -> str:
    import _cycles

    with tempfile.TemporaryDirectory(prefix="lamina_osl_") as d:
        src, dst = os.path.join(d, "shader.osl"), os.path.join(d, "shader.oso")
        with open(src, "w") as f:
            f.write(source)
        if not _cycles.osl_compile(src, dst) or not os.path.exists(dst):
            raise OslCompileError("Cycles' OSL compiler rejected the generated shader (details on stderr)")
        with open(dst) as f:
            oso = f.read()
    # The compiler records its temporary paths; drop them so the bytecode (and its hash) is deterministic.
    return "".join(line for line in oso.splitlines(keepends=True) if not line.startswith("# options:"))


def parse_params(oso: str) -> list[OsoParam]:
    """The shader's inputs and outputs, those that get sockets: array parameters (the fitted mapping's tables) keep
    their defaults, which OSL treats as constants."""
    out = []
    for line in oso.splitlines():
        fields = line.split("\t")
        if fields[0] not in ("param", "oparam") or "[" in fields[1]:
            continue
        type_, name = fields[1], fields[2]
        default = tuple(float(x) for x in fields[3].split()) if len(fields) > 3 and type_ != "closure color" else ()
        out.append(OsoParam(name, type_, fields[0] == "oparam", default))
    return out


def load_into_script_node(node, oso: str) -> None:
    """Set a ShaderNodeScript to INTERNAL bytecode and create its sockets from the .oso parameters."""
    node.mode = "INTERNAL"
    node.bytecode = oso
    node.bytecode_hash = hashlib.md5(oso.encode()).hexdigest()
    for sockets in (node.inputs, node.outputs):
        while len(sockets):
            sockets.remove(sockets[-1])
    for p in parse_params(oso):
        sockets = node.outputs if p.output else node.inputs
        socket = sockets.new(SOCKET_TYPES[p.type], p.name)
        if p.default and hasattr(socket, "default_value"):
            n = len(socket.default_value) if hasattr(socket.default_value, "__len__") else 0
            socket.default_value = p.default[0] if n == 0 else (p.default + (1.0,))[:n]
