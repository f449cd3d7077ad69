"""Cycles shaders generated from each model's mapping (``<model>.py``, bpy-free) in two forms:
a native node group (``node_backend``) and an OSL script node (``osl``); ``material`` assembles them."""
from . import spongecake

MAPPINGS = {"spongecake": spongecake}
