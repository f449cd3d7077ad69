"""bpy-free model declarations. ``MODELS`` maps the id of each layered-material model (a BSDF: eval / pdf / sample,
the comparison scenes, both Cycles forms) to its declaration module; ``MEDIA`` the participating media, whose light
is baked per object instead (no BSDF, no comparison scenes); ``REGISTRY`` holds both, for what every model has
(an Add button, a panel summary, presets)."""
from . import aniso_stack, micrograin, neural_medium, spongecake, thin_coat

MODELS = {spongecake.ID: spongecake, micrograin.ID: micrograin, thin_coat.ID: thin_coat, aniso_stack.ID: aniso_stack}
MEDIA = {neural_medium.ID: neural_medium}
REGISTRY = {**MODELS, **MEDIA}
