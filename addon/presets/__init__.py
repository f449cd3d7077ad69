"""Presets are JSON files, one per preset, in ``presets/<model id>/``, using the declaration's parameter names."""
from __future__ import annotations

import json
from pathlib import Path

ROOT = Path(__file__).parent


def names(model: str) -> list[str]:
    return sorted(p.stem for p in (ROOT / model).glob("*.json"))


def load(model: str, name: str) -> dict:
    path = ROOT / model / f"{name}.json"
    if not path.is_file():
        raise KeyError(f"unknown {model} preset {name!r}; available: {', '.join(names(model))}")
    return json.loads(path.read_text())


def description(model: str, name: str) -> str:
    return load(model, name).get("description", "")


def demo_names(model: str) -> list[str]:
    """The presets the demo runs by default (``"demo": true`` in their file): a few that show the model's range
    and keep ``make demo`` short; ``demo --all-presets`` runs every one."""
    return [name for name in names(model) if load(model, name).get("demo", False)]
