"""Exact float64 numpy references of the models (bpy-free): ``<model id>.py`` each, their math building blocks, and the
Monte Carlo ground truths ``<model id>_truth.py`` of the models that have one (``truth_module``)."""
import importlib


def truth_module(model_id: str):
    """The model's Monte Carlo ground truth of its light paths (``reference.<model id>_truth`` with
    ``ground_truth`` and ``ground_truth_albedo``), or None where there is none."""
    try:
        module = importlib.import_module(f".{model_id}_truth", __name__)
    except ImportError:
        return None
    return module if all(hasattr(module, f) for f in ("ground_truth", "ground_truth_albedo")) else None


def truth_models() -> list[str]:
    """The model ids with a Monte Carlo ground truth of their light paths (``compare --truth``), in registry order."""
    from ..models import MODELS

    return [m for m in MODELS if truth_module(m) is not None]
