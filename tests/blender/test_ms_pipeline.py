"""The whole multiple-scattering pipeline at --quick size, in CI time: Monte Carlo dataset → training → export →
the add-on loads the exported weights → a texture-driven material is baked → Cycles renders it as predicted."""
import os
import shutil

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytest.importorskip("torch")

from addon.bake import spongecake as ms  # noqa: E402
from addon.nodes import predicted_image  # noqa: E402
from addon.operators import bake_ops  # noqa: E402
from addon.operators.cycles_render import render_cycles  # noqa: E402
from addon.reference import metrics  # noqa: E402
from addon.reference import scenes as S  # noqa: E402
from training import dataset, train  # noqa: E402

from test_texture_bake import _halves, _material, _params  # noqa: E402

pytestmark = pytest.mark.blender


@pytest.fixture
def quick_weights(tmp_path, monkeypatch):
    data, weights = tmp_path / "data", tmp_path / "weights"
    assert dataset.main(["--quick", "--out", str(data), "--workers", "1"]) == 0
    assert train.main(["--quick", "--layers", "1", "--data", str(data), "--out", str(weights),
                       "--validation", str(data), "--threads", "1"]) == 0
    for n_layers in range(1, ms.ENERGY_NETWORK_LAYERS + 1):  # trained apart (training.energy_train)
        shutil.copy(ms.energy_weights_path(n_layers), weights)
    monkeypatch.setattr(ms, "WEIGHTS", weights)
    ms.forget_networks()
    yield weights
    ms.forget_networks()


def test_quick_train_export_load_bake_render(quick_weights, tmp_path):
    assert ms.network(1).manifest["training_configs"] > 0  # the freshly exported network is the one in use
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    path, received = _halves(tmp_path, "thickness")
    mat, _ = _material("thickness", path)
    summary, _ = bake_ops.bake(mat)
    assert "Baked" in summary and os.listdir(tmp_path / "lamina_cache")
    spec = S.plane_scene(resolution=(40, 20))
    img, _ = render_cycles(mat, spec, 16, 0, str(tmp_path / "render.exr"))
    assert np.all(np.isfinite(img)) and img.min() >= 0
    phi = S.pixel_geometry(spec)["phi_o"]
    left = (np.cos(phi) > 0.2)
    left[0] = False
    h, w = received.shape[:2]
    predicted = predicted_image("spongecake", _params({"thickness": float(received[h - 1, 0])}), "nodes", spec)
    assert metrics.rmse(img, predicted, left) / predicted[left].mean() < 0.05
