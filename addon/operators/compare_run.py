"""Comparison runs shared by the operator, the CLI, the demo and the benchmarks (bpy)."""
from __future__ import annotations

SCENES = ("sphere", "backlit", "furnace")
