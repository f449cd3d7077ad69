"""bpy-free model declarations. ``MODELS`` maps a model id to its declaration module."""
from . import aniso_stack, micrograin, spongecake, thin_coat

MODELS = {spongecake.ID: spongecake, micrograin.ID: micrograin, thin_coat.ID: thin_coat, aniso_stack.ID: aniso_stack}
