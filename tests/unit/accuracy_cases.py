"""Shared by test_preset_accuracy.py, test_micrograin_accuracy.py and their measuring script: the mapping's error
per preset, scene and form.

Run ``python -m tests.unit.accuracy_cases`` to print the measured errors (the thresholds in the tests come from
this output with 25% + 0.01 headroom)."""
import importlib

import numpy as np

from addon import presets
from addon.models import MODELS
from addon.nodes import predicted_image
from addon.reference import metrics
from addon.reference import scenes as S

SCENES = [S.sphere_scene(resolution=32), S.plane_scene(resolution=(32, 16)), S.backlit_scene(resolution=(32, 16)),
          S.furnace_scene(resolution=(16, 8))]


def errors(name: str, model_id: str = "spongecake") -> dict:
    """{(scene, form): rel RMSE of the form's prediction against the reference}."""
    reference = importlib.import_module(f"addon.reference.{model_id}")
    p = MODELS[model_id].params_from_dict(presets.load(model_id, name))
    out = {}
    for spec in SCENES:
        ref = S.reference_image(spec, lambda wi, wo: reference.eval(p, wi, wo),
                                bsdf_albedo=lambda wo: reference.furnace_albedo(p, wo, n=2048))
        mask = S.scene_mask(spec)
        for form in ("osl", "nodes"):
            approx = predicted_image(model_id, p, form, spec)
            assert np.all(np.isfinite(approx[mask]))
            out[(spec.name, form)] = metrics.rel_rmse(approx, ref, mask)
    return out


if __name__ == "__main__":
    for model_id in MODELS:
        for name in presets.names(model_id):
            print(model_id, name, {f"{s}/{f}": round(v, 4) for (s, f), v in errors(name, model_id).items()})
