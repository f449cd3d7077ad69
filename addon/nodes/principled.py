"""What a mapping declares when its Principled BSDF (``principled_settings``) is a like-for-like comparison: Blender's
Principled BSDF set up from the same parameters, rendered beside the model in comparisons (``compare --principled``,
the compare panel's checkbox). A mapping without ``PRINCIPLED`` (or with None) has a Principled BSDF of about the same
lobe count only: the render-time baseline of the demo and the benchmarks, not compared."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Counterpart:
    """``label``: the Principled BSDF's name in pictures and summaries; ``mapping``: one line saying how it is set up
    from the model's parameters (recorded in comparison reports)."""

    label: str
    mapping: str
