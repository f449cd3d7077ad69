"""Comparing porous layers with the reference: the blends side by side (linear mix by τ0, d'Eon et al.'s weighting),
the CLI and the compare operator, and the refusal for a layer over a material's own shader."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import addon  # noqa: E402
from addon import presets  # noqa: E402
from addon.bake.exr import read_exr, read_png  # noqa: E402
from addon.models import micrograin as model  # noqa: E402
from addon.nodes import material  # noqa: E402
from addon.operators import compare_run  # noqa: E402
from addon.reference import metrics  # noqa: E402
from addon.reference import micrograin as ref  # noqa: E402
from addon.reference import scenes as S  # noqa: E402

pytestmark = pytest.mark.blender
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.fixture(autouse=True)
def clean_file():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield


def test_blends_are_rendered_beside_ours_and_differ_from_it(tmp_path):
    p = model.params_from_dict(presets.load(model.ID, "soot_on_clay"))
    report = compare_run.compare_params(model.ID, p, ["nodes"], ["sphere"], 8, 16, 0, str(tmp_path), blends=True)
    entry = report["forms"]["nodes"]["sphere"]
    spec = S.sphere_scene(resolution=16)
    ours = read_exr(str(tmp_path / entry["files"]["reference"]), "RGB")
    linear = S.reference_image(spec, lambda wi, wo: ref.eval(p, wi, wo, blend="linear"))
    assert entry["blends"]["vs_ours"]["linear"] == pytest.approx(metrics.rel_rmse(linear, ours, S.scene_mask(spec)))
    assert min(entry["blends"]["vs_ours"].values()) > 0.01  # the weights differ visibly on soot over clay
    picture = read_png(str(tmp_path / entry["blends"]["files"]["blends_picture"]))
    assert picture.shape[1] == 4 * 16 + 3 * 2 and entry["blends"]["panels"] == ["Cycles", "ours", "linear", "deon"]
    on_disk = json.loads((tmp_path / "report.json").read_text())
    assert on_disk["forms"]["nodes"]["sphere"]["blends"]["vs_ours"] == entry["blends"]["vs_ours"]


def test_the_compare_operator_runs_on_a_porous_layer_and_refuses_a_wrapped_shader():
    addon.register()
    try:
        p = model.params_from_dict(presets.load(model.ID, "gold_spray_paint"))
        mat = material.new_material(model.ID, p, "nodes")
        settings = bpy.context.window_manager.lamina_compare
        settings.samples, settings.resolution, settings.scene, settings.blends = 4, 16, "sphere", True
        with bpy.context.temp_override(material=mat):
            assert bpy.ops.lamina.compare() == {"FINISHED"}
        assert "other blends vs ours" in settings.last_report
        wrapped = material.new_material(model.ID, model.params_from_dict({"bulk": {"type": "shader"}}), "nodes")
        with bpy.context.temp_override(material=wrapped), pytest.raises(RuntimeError, match="no reference"):
            bpy.ops.lamina.compare()
    finally:
        addon.unregister()


@pytest.mark.version_independent("a CLI pipeline in a subprocess; the compare operator runs under 4.2 too")
def test_cli_compare_micrograin_and_its_refusals(tmp_path):
    def cli(*args):
        return subprocess.run([sys.executable, "-m", "addon.cli", *args], cwd=ROOT, capture_output=True, text=True)

    out = tmp_path / "rust"
    done = cli("compare", "--model", "micrograin", "--preset", "rust_on_metal", "--blends", "--forms", "osl",
               "--scenes", "sphere", "--samples", "4", "--resolution", "16", "--out", str(out))
    assert done.returncode == 0, done.stderr
    report = json.loads((out / "report.json").read_text())
    assert set(report["forms"]["osl"]["sphere"]["blends"]["vs_ours"]) == {"linear", "deon"}
    (tmp_path / "wrapped.json").write_text(json.dumps({"bulk": {"type": "shader"}}))
    refused = cli("compare", "--model", "micrograin", "--params", str(tmp_path / "wrapped.json"), "--out",
                  str(tmp_path / "no"))
    assert refused.returncode == 2 and "no reference" in refused.stderr and not (tmp_path / "no").exists()
    refused = cli("compare", "--preset", "fabric", "--blends", "--out", str(tmp_path / "no"))
    assert refused.returncode == 2 and "single blending weight" in refused.stderr
    assert np.isfinite(report["forms"]["osl"]["sphere"]["rel_rmse"])
