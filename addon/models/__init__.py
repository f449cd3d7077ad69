"""bpy-free model declarations. ``MODELS`` maps a model id to its declaration module."""
from . import micrograin, spongecake

MODELS = {spongecake.ID: spongecake, micrograin.ID: micrograin}
