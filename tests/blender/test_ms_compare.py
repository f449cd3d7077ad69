"""Comparison with multiple scattering (compare_run ``ms``, the CLI's ``compare --ms``, the compare operator's
"Multiple scattering" checkbox): SS only, SS + MS (network) and SS + MS (Monte Carlo) on every scene, small sizes.
No predicted number is hard-coded: the shipped weights change with training."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import addon  # noqa: E402
from addon import presets  # noqa: E402
from addon.reference import montecarlo  # noqa: E402
from addon.reference import spongecake_truth as ms_truth  # noqa: E402
from addon.bake.exr import read_exr, read_png  # noqa: E402
from addon.models import spongecake as model  # noqa: E402
from addon.nodes import material  # noqa: E402
from addon.operators import compare_run  # noqa: E402
from addon.reference import metrics  # noqa: E402
from addon.reference import scenes as S  # noqa: E402
from addon.reference import spongecake as ref  # noqa: E402

pytestmark = pytest.mark.blender
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SMALL = ms_truth.TruthSettings(paths=160, albedo_paths=160, stride=2)
KEYS = ("cycles_vs_network", "network_vs_truth", "single_vs_truth", "cycles_vs_truth", "truth_noise", "truth_mean",
        "ms_share", "truth_pixels", "truth_paths", "truth_stride", "truth_seconds", "files")
MS_NUMERICS = pytest.mark.version_independent(
    "the multiple-scattering comparison's numpy numerics and report (its Cycles render: test_cycles_harness)")
CLI = pytest.mark.version_independent("a CLI pipeline in a subprocess; the compare operator runs under 4.2 too")


def _forget_energy_tables():
    ref._energy_tables.cache_clear()  # the Cycles forms' budget tables do not depend on ENERGY_AZIMUTHS


@pytest.fixture(scope="module")
def fabric_report(tmp_path_factory):
    """The oriented fabric compared with its reference energy tables at 4 view azimuths instead of 32 (the same
    samples per view; what is asserted does not depend on their count): half the comparison's time. The tables are forgotten
    afterwards, so no other test sees them."""
    out = tmp_path_factory.mktemp("ms_compare")
    p = model.params_from_dict(presets.load(model.ID, "fabric"))  # flag off in the preset: --ms turns it on
    counts = {c: len(getattr(bpy.data, c)) for c in ("scenes", "objects", "materials", "node_groups", "images")}
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(model, "ENERGY_AZIMUTHS", 4)
        _forget_energy_tables()
        try:
            report = compare_run.compare_params(model.ID, p, ["nodes"], list(S.KINDS), 4, 16, 0, str(out),
                                                label="fabric", ms=SMALL)
        finally:
            _forget_energy_tables()
    assert {c: len(getattr(bpy.data, c)) for c in counts} == counts  # everything temporary is gone
    return out, p, report


@MS_NUMERICS
def test_every_scene_reports_the_three_comparisons(fabric_report):
    out, _, report = fabric_report
    assert report["params"]["multiple_scattering"] is True
    assert report["ms"]["paths"] == SMALL.paths and report["ms"]["stride"] == SMALL.stride
    on_disk = json.loads((out / "report.json").read_text())
    for scene in S.KINDS:
        m = on_disk["forms"]["nodes"][scene]["ms"]
        assert set(KEYS) <= set(m)
        assert all(np.isfinite(m[k]) and m[k] >= 0 for k in KEYS if k != "files"), m
        assert m["cycles_vs_network"] == pytest.approx(on_disk["forms"]["nodes"][scene]["rel_rmse"])
        assert 0 < m["truth_pixels"] < S.scene_mask(compare_run.scene_specs([scene], 16)[0]).sum()
        for path in m["files"].values():
            assert (out / path).exists()


@MS_NUMERICS
def test_images_and_numbers_agree(fabric_report):
    """The written single-scattering and ground-truth images reproduce the reported errors, and the single
    scattering image is the closed-form reference of the flag-off stack."""
    out, p, report = fabric_report
    spec = compare_run.scene_specs(["plane"], 16)[0]
    entry = report["forms"]["nodes"]["plane"]
    files = {k: str(out / v) for k, v in entry["ms"]["files"].items()}
    single = read_exr(files["single"], "RGB")
    truth = read_exr(files["ground_truth"], "RGB")
    network = read_exr(str(out / entry["files"]["reference"]), "RGB")
    expected_single = S.reference_image(spec, lambda wi, wo: ref.eval(p, wi, wo))
    np.testing.assert_allclose(single, expected_single, rtol=1e-5, atol=1e-7)  # EXR is float32
    samples = montecarlo.sampled_pixels(spec, SMALL.stride)
    assert metrics.rel_rmse(single, truth, samples) == pytest.approx(entry["ms"]["single_vs_truth"], rel=1e-4)
    assert metrics.rel_rmse(network, truth, samples) == pytest.approx(entry["ms"]["network_vs_truth"], rel=1e-4)
    assert np.all(truth[samples] >= single[samples] - 1e-6)  # orders >= 2 only add light
    picture = read_png(files["ms_picture"])
    assert picture.shape[0] == spec.height and picture.shape[1] == 6 * spec.width + 5 * 2


@MS_NUMERICS
def test_summary_names_the_monte_carlo_noise(fabric_report):
    text = compare_run.summary_lines(fabric_report[2])
    assert text.count("multiple scattering vs Monte Carlo") == len(S.KINDS)
    assert "Monte Carlo noise" in text and f"x {SMALL.paths} paths" in text


def test_a_material_with_the_flag_off_is_compared_through_a_temporary_copy(tmp_path):
    p = model.params_from_dict({"layers": [{"type": "hg", "roughness": 0.2, "albedo": [0.9] * 3}]})
    mat = material.new_material(model.ID, p, "nodes", name="mine")
    try:
        before = {c: len(getattr(bpy.data, c)) for c in ("materials", "node_groups", "scenes", "objects")}
        report = compare_run.compare_material(mat, ["furnace"], 4, 16, 0, str(tmp_path), ms=SMALL)
        assert {c: len(getattr(bpy.data, c)) for c in before} == before
        assert material.current_params(mat)[1].multiple_scattering is False  # the user's material is untouched
        m = report["furnace"]["ms"]
        assert m["ms_share"] > 0.05  # a bright medium: orders >= 2 matter in the furnace
    finally:
        bpy.data.materials.remove(mat)


def test_compare_operator_with_the_multiple_scattering_checkbox():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    addon.register()
    try:
        obj = bpy.data.objects.new("ball", bpy.data.meshes.new("ball"))
        bpy.context.scene.collection.objects.link(obj)
        bpy.context.view_layer.objects.active = obj
        bpy.ops.lamina.add_spongecake(preset="thick_flakes", form="nodes")
        mat = obj.active_material
        settings = bpy.context.window_manager.lamina_compare
        settings.samples, settings.resolution, settings.scene = 4, 16, "plane"
        settings.multiple_scattering, settings.ms_paths = True, 160
        with bpy.context.temp_override(material=mat):
            assert bpy.ops.lamina.compare() == {"FINISHED"}
        assert "multiple scattering vs Monte Carlo" in settings.last_report
        assert "Lamina Compare" in bpy.data.images
    finally:
        addon.unregister()


def _lamina(*args):
    return subprocess.run([sys.executable, "-m", "addon.cli", *args], capture_output=True, text=True, cwd=ROOT,
                          env=dict(os.environ, PYTHONPATH=ROOT), timeout=600)


@CLI
def test_cli_compare_ms_refuses_too_few_paths(tmp_path):
    r = _lamina("compare", "--preset", "fabric", "--ms", "--ms-paths", "1", "--out", str(tmp_path))
    assert r.returncode == 2 and "--ms-paths" in r.stderr


@CLI
def test_cli_compare_ms_writes_the_comparison(tmp_path):
    # leaf: it lets light through to the backlit scene, and its layers lie along the normal: one view azimuth for the
    # energy tables the subprocess computes afresh (an oriented stack such as window_shade takes 32: minutes; the
    # fabric comparison above measures one in-process); the analytic mapping: no fit, whatever the fit cache holds
    r = _lamina("compare", "--preset", "leaf", "--mapping", "analytic", "--ms", "--forms", "osl", "--scenes",
                "backlit", "--samples", "4", "--resolution", "12", "--ms-paths", "80", "--out", str(tmp_path))
    assert r.returncode == 0, r.stderr
    assert "multiple scattering vs Monte Carlo" in r.stdout
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["forms"]["osl"]["backlit"]["ms"]["truth_paths"] == 80
    assert (tmp_path / "osl" / "backlit_ms.png").exists()
