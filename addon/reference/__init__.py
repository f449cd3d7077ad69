"""Exact float64 numpy references of the models (bpy-free): ``spongecake`` and its math building blocks."""
