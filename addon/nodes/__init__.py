"""Cycles shaders generated from each model's mapping (``<model>.py``, bpy-free) in two forms:
a native node group (``node_backend``) and an OSL script node (``osl``); ``material`` assembles them."""
from . import spongecake

MAPPINGS = {"spongecake": spongecake}


def predicted_eval(model_id: str, p, form: str):
    """``f(wi, wo)`` of what Cycles renders for ``p`` in ``form``, computed in numpy from the same mapping."""
    from .expr import NumpyBackend

    mapping = MAPPINGS[model_id]
    values = mapping.input_values(p)

    def evaluate(wi, wo):
        b = NumpyBackend(wo, values, form)
        mapping.shade(b, p)
        return b.evaluate(wi)

    return evaluate
