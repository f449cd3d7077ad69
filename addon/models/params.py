"""Parameter declarations: the single source of truth read by the reference, UI, node groups, OSL and CLI.

A model module declares its parameters once as ``Param`` tuples. Everything that shows, stores or
generates a parameter (node-group sockets, OSL parameter lists, presets, the CLI) iterates these
declarations instead of naming parameters again.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field


# Keys of a preset or parameter dict that describe it rather than the material: validation accepts and ignores them
# (``name``; ``description``, shown with a preset; ``demo``: the preset is in the demo's default selection).
METADATA_KEYS = ("name", "description", "demo")


class ParamError(ValueError):
    """A parameter value that cannot be clamped into something meaningful (wrong type, unknown name)."""


@dataclass(frozen=True)
class Param:
    name: str
    label: str
    kind: str  # "float" | "int" | "color" | "vector" | "enum" | "bool"
    default: object
    min: float | None = None
    max: float | None = None
    unit: str = ""
    texturable: bool = False
    description: str = ""
    items: tuple = ()  # enum identifiers
    subtype: str = ""  # Blender socket subtype hint: "FACTOR", "DIRECTION", ...

    def clamp(self, value, where: str, warnings: list[str]):
        """Return ``value`` coerced to this parameter's kind and range; append a message when it changes."""
        if self.kind == "enum":
            if value not in self.items:
                raise ParamError(f"{where}{self.name}: unknown value {value!r}; expected one of {', '.join(self.items)}")
            return value
        if self.kind == "bool":
            if not isinstance(value, (bool, int)):
                raise ParamError(f"{where}{self.name}: expected true or false, got {value!r}")
            return bool(value)
        if self.kind == "float":
            return self._clamp_scalar(_as_float(value, where, self.name), where, warnings)
        if self.kind == "int":
            v = _as_float(value, where, self.name)
            if not v.is_integer():
                raise ParamError(f"{where}{self.name}: expected a whole number, got {value!r}")
            return int(self._clamp_scalar(v, where, warnings))
        values = _as_triple(value, where, self.name)
        if self.kind == "vector":
            return _normalized(values, self.default, where, self.name, warnings)
        return tuple(self._clamp_scalar(v, where, warnings, channel=i) for i, v in enumerate(values))

    def _clamp_scalar(self, v: float, where: str, warnings: list[str], channel: int | None = None) -> float:
        """``v`` clamped into [min, max]; a non-finite value takes the default (of its channel for colours)."""
        name = self.name if channel is None else f"{self.name}[{channel}]"
        if not math.isfinite(v):
            d = float(self.default if channel is None else self.default[channel])
            warnings.append(f"{where}{name}: {v} is not finite, using the default {d:g}")
            return d
        lo = -math.inf if self.min is None else self.min
        hi = math.inf if self.max is None else self.max
        c = min(max(v, lo), hi)
        if c != v:
            warnings.append(f"{where}{name}: {v:g} is outside [{lo:g}, {hi:g}], clamped to {c:g}")
        return c


@dataclass
class Validated:
    """A clean parameter object plus the messages produced while cleaning it."""

    params: object
    warnings: list[str] = field(default_factory=list)


def _as_float(value, where: str, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParamError(f"{where}{name}: expected a number, got {value!r}")
    return float(value)


def _as_triple(value, where: str, name: str) -> tuple[float, float, float]:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return (float(value),) * 3
    if isinstance(value, (str, bytes, dict)):
        raise ParamError(f"{where}{name}: expected three numbers, got {value!r}")
    try:
        values = tuple(_as_float(v, where, name) for v in value)
    except TypeError:
        raise ParamError(f"{where}{name}: expected three numbers, got {value!r}") from None
    if len(values) != 3:
        raise ParamError(f"{where}{name}: expected three numbers, got {len(values)}")
    return values


def _normalized(v, default, where: str, name: str, warnings: list[str]):
    n = math.sqrt(sum(x * x for x in v)) if all(math.isfinite(x) for x in v) else 0.0
    if n < 1e-12:
        warnings.append(f"{where}{name}: {v} has no direction, using the default {tuple(default)}")
        return tuple(float(x) for x in default)
    return tuple(x / n for x in v)


def read_fields(decl: tuple[Param, ...], data: dict, where: str, warnings: list[str]) -> dict:
    """Validate the declared fields of ``data`` (missing ones take their defaults, unknown names are refused)."""
    known = {p.name for p in decl}
    unknown = sorted(set(data) - known)
    if unknown:
        expected = f"expected {', '.join(sorted(known))}" if known else "it takes none"
        raise ParamError(f"{where}unknown parameter(s) {', '.join(unknown)}; {expected}")
    return {p.name: p.clamp(data.get(p.name, p.default), where, warnings) for p in decl}
