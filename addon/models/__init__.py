"""bpy-free model declarations. ``MODELS`` maps a model id to its declaration module."""
from . import spongecake

MODELS = {spongecake.ID: spongecake}
