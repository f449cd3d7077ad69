"""Cycles shaders generated from each model's mapping (``<model>.py``, bpy-free) in two forms:
a native node group (``node_backend``) and an OSL script node (``osl``); ``material`` assembles them."""
from . import aniso_stack, bulk, fitted, micrograin, pruning, spongecake, thin_coat

# Model id -> mapping; "bulk" is the simple BSDFs that reference bulks under a porous layer are made of.
MAPPINGS = {"spongecake": spongecake, "micrograin": micrograin, "thin_coat": thin_coat, "aniso_stack": aniso_stack,
            bulk.ID: bulk}
FORMS = ("nodes", "osl")  # node group (every device) and OSL script (CPU, OptiX)
FORM_LABELS = {"nodes": "node group", "osl": "OSL"}
# How a material's closures are found (independent of the form): the mapping's own formulas, the fitted tables
# (``fitted``), or whichever of the two the comparison scenes measure closer to the reference (``choice``).
MAPPING_KINDS = ("analytic", "fitted", "auto")


def fittable(model_id: str) -> bool:
    """Whether the model's mapping offers the fitted mapping (its ``FITTABLE``)."""
    return getattr(MAPPINGS.get(model_id), "FITTABLE", False)


def approximations(model_id: str, p) -> list[tuple[str, str]]:
    """(name, what it does) of each approximation the mapping makes for ``p`` (``approximations_used``), then those
    of the mapping of what it wraps (a porous layer's bulk of another model), named "<model>: <name>"."""
    mapping = MAPPINGS[model_id]
    out = [(name, mapping.APPROXIMATIONS[name][0]) for name in mapping.approximations_used(p)]
    inner = mapping.bulk_shader(p) if hasattr(mapping, "bulk_shader") else None
    if inner is not None and hasattr(MAPPINGS[inner[0]], "approximations_used"):
        out += [(f"{inner[0]}: {name}", what) for name, what in approximations(*inner)]
    return out


def principled_counterpart(model_id: str):
    """The mapping's ``PRINCIPLED`` (``principled.Counterpart``: label and one-line mapping) where its Principled BSDF
    (``principled_settings``) renders the same material, compared beside it (``compare --principled``); None where
    it only has about the same lobe count (the render-time baseline)."""
    return getattr(MAPPINGS.get(model_id), "PRINCIPLED", None)


def principled_models() -> list[str]:
    """The model ids whose mapping has a ``principled_counterpart``, in registry order."""
    return [m for m in MAPPINGS if principled_counterpart(m) is not None]


def numpy_backend(model_id: str, p, form: str, wo, texels=None):
    """A ``NumpyBackend`` for ``p`` at the views ``wo``, no closures yet; ``texels``: as ``view_inputs``' (``p`` is
    then one texel's values)."""
    from .expr import NumpyBackend

    mapping = MAPPINGS[model_id]
    bulk = mapping.numpy_bulk(p, form) if hasattr(mapping, "numpy_bulk") else None
    return NumpyBackend(wo, {**input_values(model_id, p, form), **view_inputs(model_id, p, form, texels)}, form, bulk)


def input_values(model_id: str, p, form: str) -> dict:
    """Socket name → value of every input of ``form``'s shader for ``p``: the model parameters (the mapping's
    ``input_values``) and what Lamina bakes for that form (its ``baked_values``: SpongeCake's multiple scattering)."""
    mapping = MAPPINGS[model_id]
    baked = mapping.baked_values(p, form) if hasattr(mapping, "baked_values") else {}
    return {**mapping.input_values(p), **baked}


def view_inputs(model_id: str, p, form: str, texels=None) -> dict:
    """The inputs that ``form``'s shader is fed from a table over the view direction (the mapping's ``view_inputs``:
    socket name → ``view_table.ViewTable``; ``view_wiring`` links them), none for most mappings; ``texels``: how the
    tables follow the texels of a texture-driven material (SpongeCake's ``TexelEnergy``), None for constant inputs."""
    mapping = MAPPINGS[model_id]
    return mapping.view_inputs(p, form, texels) if hasattr(mapping, "view_inputs") else {}


def _backend(model_id: str, p, form: str, wo, fit=None, texels=None):
    b = numpy_backend(model_id, p, form, wo, texels)
    shade(b, model_id, p, fit)
    return b


def shade(b, model_id: str, p, fit=None) -> None:
    """The closures of ``p`` on backend ``b``: the mapping's own (``fit`` None), the fitted ones (a ``fitted.Fit``),
    or the mapping's own less those a ``pruning.Pruned`` leaves out."""
    if fit is None:
        MAPPINGS[model_id].shade(b, p)
    elif isinstance(fit, pruning.Pruned):
        pruning.shade(b, MAPPINGS[model_id], p, fit)
    else:
        fitted.shade(b, MAPPINGS[model_id], p, fit, lambda wo: numpy_backend(model_id, p, b.form, wo))


def predicted_eval(model_id: str, p, form: str, fit=None):
    """``f(wi, wo)`` of what Cycles renders for ``p`` in ``form``, computed in numpy from the same mapping (the
    fitted one with ``fit``)."""
    return lambda wi, wo: _backend(model_id, p, form, wo, fit).evaluate(wi)


def predicted_furnace(model_id: str, p, form: str, fit=None, texels=None, quadratures=None):
    """``a(wo)``: what a white furnace shows through the form (``expr.closure_furnace``, with its ``quadratures``);
    with ``texels`` (``view_inputs``'), what one texel of values ``p`` of a texture-driven material shows."""
    from .expr import closure_furnace

    extra = {} if quadratures is None else {"quadratures": quadratures}
    return lambda wo: closure_furnace(lambda w: _backend(model_id, p, form, w, fit, texels), wo, **extra)


def predicted_image(model_id: str, p, form: str, scene, fit=None):
    """A comparison scene as the form renders it (no sampling noise)."""
    from ..reference.scenes import reference_image

    return reference_image(scene, predicted_eval(model_id, p, form, fit),
                           bsdf_albedo=predicted_furnace(model_id, p, form, fit))
