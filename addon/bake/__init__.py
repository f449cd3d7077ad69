"""Baking: network inference, per-material and per-texel parameter maps, EXR/PNG I/O, caching."""
