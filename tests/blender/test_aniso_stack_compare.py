"""Comparing anisotropic stacks beside Blender's Principled BSDF set up from the same parameters (issue 12: the
mapping declares it, ``nodes.aniso_stack.PRINCIPLED``, and the generic comparison renders it), also against the Monte
Carlo ground truth of the explicit stack. Tiny renders only (16 px, 4 samples, the sphere)."""
import json

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from addon import presets  # noqa: E402
from addon.models import aniso_stack as model  # noqa: E402
from addon.nodes import aniso_stack as mapping  # noqa: E402
from addon.nodes import material  # noqa: E402
from addon.operators import compare_run  # noqa: E402
from ui_helpers import panel_text  # noqa: E402

pytestmark = pytest.mark.blender
PRESET = "rough_tangents_30"


@pytest.fixture(autouse=True)
def clean_file():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield


def test_has_principled_follows_the_mappings():
    assert compare_run.has_principled("thin_coat") and compare_run.has_principled(model.ID)
    assert not compare_run.has_principled("spongecake") and not compare_run.has_principled("micrograin")


def test_compare_params_with_the_principled_bsdf_and_the_ground_truth(tmp_path):
    p = model.params_from_dict(presets.load(model.ID, PRESET))
    truth = compare_run.CoatTruth(paths=16, stride=8)
    report = compare_run.compare_params(model.ID, p, ["nodes"], ["sphere"], 4, 16, 0, str(tmp_path),
                                        principled=True, truth=truth)
    on_disk = json.loads((tmp_path / "report.json").read_text())
    settings = mapping.principled_settings(p)
    assert on_disk["principled"]["mapping"] == mapping.PRINCIPLED.mapping
    assert on_disk["principled"]["label"] == "Principled BSDF"
    assert on_disk["principled"]["settings"]["Anisotropic"] == pytest.approx(settings["Anisotropic"])
    assert on_disk["principled"]["settings"]["Coat IOR"] == pytest.approx(1.49)
    e = on_disk["forms"]["nodes"]["sphere"]
    pr = e["principled"]
    for key in ("rel_rmse", "rmse", "max_abs_error"):
        assert np.isfinite(pr[key]) and pr[key] >= 0.0, key
    assert pr["panels"][2] == "Principled BSDF"
    assert pr["lamina_rel_rmse"] == pytest.approx(e["rel_rmse"], rel=1e-3)  # the render read back from its EXR
    assert (tmp_path / pr["files"]["principled"]).is_file()
    assert (tmp_path / pr["files"]["principled_picture"]).is_file()
    t = e["truth"]
    assert np.isfinite(t["principled_vs_truth"]) and t["principled_vs_truth"] >= 0.0
    assert np.isfinite(t["cycles_vs_truth"]) and t["truth_pixels"] > 0
    text = compare_run.summary_lines(report)
    assert "Principled BSDF vs reference: rel. RMSE" in text and ", Principled " in text
    assert not any(m.name.startswith("Lamina compare") for m in bpy.data.materials)  # temporaries removed


def test_the_compare_panel_offers_the_principled_bsdf(registered, sphere):
    p = model.params_from_dict(presets.load(model.ID, PRESET))
    text = panel_text(material.new_material(model.ID, p, "nodes"))
    assert any(line.endswith(" principled") for line in text.splitlines()) and "lamina.compare" in text
