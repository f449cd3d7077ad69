"""Comparing thin coats: Cycles vs the reference on the usual scenes (backlit only for the slab), beside Blender's
Principled BSDF coat set up from the same parameters (its mapping, its picture panel and its RMSE in the report),
the Monte Carlo ground truth at sampled pixels, the CLI and the compare operator. Tiny renders only."""
import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import addon  # noqa: E402
from addon import presets  # noqa: E402
from addon.bake.exr import read_exr, read_png  # noqa: E402
from addon.models import thin_coat as model  # noqa: E402
from addon.nodes import material, principled_coat  # noqa: E402
from addon.operators import compare_run  # noqa: E402
from addon.reference import metrics, microfacet  # noqa: E402
from addon.reference import scenes as S  # noqa: E402
from addon.reference import thin_coat as ref  # noqa: E402

pytestmark = pytest.mark.blender
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SLAB = {"kappa_top": 300, "kappa_bottom": 300, "eta": 1.5, "sigma_a": [0.2, 0.4, 0.8], "depth": 0.5, "bounces": 1,
        "base": {"type": "slab"}}


@pytest.fixture(autouse=True)
def clean_file():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield


def _preset(name):
    return model.params_from_dict(presets.load(model.ID, name))


# ------------------------------------------------------------------------------------ the Principled mapping


@pytest.mark.parametrize("name", presets.names(model.ID))
def test_the_principled_mapping_is_the_stated_one(name):
    p = _preset(name)
    s = principled_coat.settings(p)
    assert s["Coat Weight"] == 1.0 and s["Coat IOR"] == p.eta
    alpha = math.sqrt(2.0 / p.kappa_top)  # the Beckmann alpha of the top's vMF lobe, taken as GGX alpha
    assert s["Coat Roughness"] == pytest.approx(min(math.sqrt(alpha), 1.0))
    assert s["Coat Tint"] == pytest.approx([math.exp(-2.0 * a * p.depth) for a in p.sigma_a])  # down and up
    assert s["Roughness"] == pytest.approx(min((2.0 / p.kappa_bottom) ** 0.25, 1.0))
    if p.base.type == "diffuse":
        assert s["Base Color"] == p.base.albedo and s["Specular IOR Level"] == 0.0 and s["Metallic"] == 0.0
    elif p.base.type == "dielectric_rough":
        assert s["Base Color"] == (0.0, 0.0, 0.0) and s["IOR"] == pytest.approx(p.base.ior / p.eta)
    elif p.base.type == "conductor":
        eta, k = np.array(p.base.eta) / p.eta, np.array(p.base.k) / p.eta
        exact = lambda c: microfacet.fresnel_conductor(np.array([c]), eta, k)[0]  # noqa: E731
        assert s["Metallic"] == 1.0 and s["Base Color"] == pytest.approx(exact(1.0))
        # Cycles' F82-tint metal: Schlick(F0) x tint at cos = 1/7 gives the exact conductor there (no clipping here)
        f0, c = np.array(s["Base Color"]), 1.0 / 7.0
        schlick = f0 + (1.0 - f0) * (1.0 - c) ** 5
        assert np.all(np.array(s["Specular Tint"]) < 1.0)
        assert schlick * np.array(s["Specular Tint"]) == pytest.approx(exact(c))


def test_a_slab_is_a_coated_glass_tinted_once():
    p = model.params_from_dict(SLAB)
    s = principled_coat.settings(p)
    assert s["Transmission Weight"] == 1.0 and s["IOR"] == 1.5
    assert s["Coat Tint"] == pytest.approx([math.exp(-a * p.depth) for a in p.sigma_a])


def test_the_principled_material_holds_the_settings():
    p = _preset("varnished_metal")
    mat = material.principled_material(model.ID, p)
    bsdf = next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    out = next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    assert out.inputs["Surface"].links[0].from_node == bsdf
    for name, value in principled_coat.settings(p).items():
        got = bsdf.inputs[name].default_value
        assert (tuple(got)[:3] if hasattr(got, "__len__") else got) == pytest.approx(value, rel=1e-6), name


def test_principled_comparison_renders_once_per_scene_and_reports_its_error(tmp_path):
    """Without a Lamina material: the Principled coat on the sphere against the reference (the "Lamina" image is
    a stand-in), its picture panels, its files and the cache shared by the forms."""
    p = _preset("glazed_ceramic")
    spec = S.sphere_scene(resolution=16)
    reference = S.reference_image(spec, lambda wi, wo: ref.eval(p, wi, wo))
    mask = S.scene_mask(spec)
    lamina = reference + 0.1 * reference[mask].mean()
    cache = {}
    entry = compare_run.principled_comparison(model.ID, p, spec, lamina, reference, 8, 0, str(tmp_path), cache)
    image = read_exr(entry["files"]["principled"], "RGB")
    assert entry["rel_rmse"] == pytest.approx(metrics.rel_rmse(image, reference, mask), rel=1e-6)
    assert entry["lamina_rel_rmse"] == pytest.approx(0.1, rel=1e-6)
    assert 0.0 < entry["rel_rmse"] < 5.0 and np.all(np.isfinite(image)) and image[mask].mean() > 0
    picture = read_png(entry["files"]["principled_picture"])
    assert picture.shape[:2] == (16, 5 * 16 + 4 * 2) and entry["panels"][2] == "Principled coat"
    again = compare_run.principled_comparison(model.ID, p, spec, lamina, reference, 8, 0, str(tmp_path / "b"), cache)
    assert again["cycles_seconds"] == entry["cycles_seconds"]  # rendered once, read from the cache
    assert len(bpy.data.materials) == 0 and len(bpy.data.scenes) == 1  # nothing left behind


def test_default_scenes_show_backlit_only_for_a_slab():
    assert compare_run.default_scene_names(_preset("amber_lacquer")) == ["sphere", "plane", "furnace"]
    assert compare_run.inapplicable_scenes(_preset("amber_lacquer")) == {"backlit": compare_run.OPAQUE}
    assert compare_run.default_scene_names(model.params_from_dict(SLAB)) == list(S.KINDS)


# ------------------------------------------------------------------------------------ the ground truth


@pytest.mark.parametrize("kind", ["plane", "furnace"])
def test_coat_truth_image_is_the_simulation_at_sampled_pixels(kind):
    """Each sampled pixel is the sum over orders of the simulated f times the sun's irradiance and cos θi (the
    furnace: the simulated albedo), in the pixel's shading frame, with the pixel's own seed; other pixels copy
    their nearest sample (pictures only) and carry no noise."""
    from addon.reference import thin_coat_truth as truth

    p = model.params_from_dict({"kappa_top": 3000, "kappa_bottom": 30, "eta": 1.5, "bounces": 1,
                                "base": {"type": "diffuse", "albedo": [0.6, 0.6, 0.6]}})
    spec = S.plane_scene(resolution=(16, 8)) if kind == "plane" else S.furnace_scene(resolution=(8, 4))
    settings = compare_run.CoatTruth(paths=64, stride=4)
    mc = compare_run.coat_truth_image(model.ID, p, spec, settings)
    samples = mc["samples"]
    rows, cols = np.nonzero(samples)
    assert len(rows) == samples.sum() > 0 and np.all(mc["noise"][~samples] == 0)
    assert np.all(np.isfinite(mc["image"])) and np.all(mc["image"] >= 0)
    g = S.pixel_geometry(spec)
    j = len(rows) - 1
    r, c = rows[j], cols[j]
    frame = (g["t"][r, c], g["b"][r, c], g["n"][r, c])
    wo = S.to_local(g["wo"][r, c], *frame)
    seed = int(np.random.SeedSequence([settings.seed, j]).generate_state(1)[0])
    if kind == "plane":
        wi = S.to_local(np.asarray(spec.suns[0].direction), *frame)
        f, _ = truth.ground_truth(p, wi[None], wo, n_paths=settings.paths, seed=seed)
        expected = f.sum(axis=0)[0] * wi[2] * spec.suns[0].irradiance
    else:
        a = truth.ground_truth_albedo(p, wo, n_paths=settings.paths, seed=seed)
        expected = spec.environment * (a["reflection"].sum(axis=0) + a["transmission"].sum(axis=0))
    assert mc["image"][r, c] == pytest.approx(expected, rel=1e-12)


# ------------------------------------------------------------------------------------ with the mapping


def test_compare_params_with_the_principled_coat(tmp_path):
    p = _preset("varnished_metal")
    report = compare_run.compare_params(model.ID, p, ["nodes"], None, 4, 16, 0, str(tmp_path), principled=True)
    entries = report["forms"]["nodes"]
    assert list(entries) == ["sphere", "plane", "furnace"]  # no backlit for a coat over a metal
    on_disk = json.loads((tmp_path / "report.json").read_text())
    assert on_disk["principled"]["settings"]["Coat Roughness"] == pytest.approx((2.0 / 1000.0) ** 0.25)
    for scene, e in on_disk["forms"]["nodes"].items():
        assert np.isfinite(e["principled"]["rel_rmse"]) and np.isfinite(e["rel_rmse"]), scene
        assert (tmp_path / e["principled"]["files"]["principled_picture"]).is_file()
    assert "Principled coat vs reference: rel. RMSE" in compare_run.summary_lines(report)


def test_the_compare_operator_shows_the_principled_panel():
    addon.register()
    try:
        mat = material.new_material(model.ID, model.params_from_dict(SLAB), "nodes")
        settings = bpy.context.window_manager.lamina_compare
        settings.samples, settings.resolution, settings.scene, settings.principled = 4, 16, "backlit", True
        with bpy.context.temp_override(material=mat):
            assert bpy.ops.lamina.compare() == {"FINISHED"}
        assert "backlit: RMSE" in settings.last_report and "Principled coat vs reference" in settings.last_report
        shown = bpy.data.images["Lamina Compare"]
        assert tuple(shown.size) == (5 * 16 + 4 * 2, 8)  # the Principled picture: five panels
    finally:
        addon.unregister()


@pytest.mark.version_independent("a CLI pipeline in a subprocess; the compare operator with the Principled "
                                  "coat runs under 4.2 too")
def test_cli_compare_thin_coat_with_principled_and_truth(tmp_path):
    args = [sys.executable, "-m", "addon.cli", "compare", "--model", "thin_coat", "--preset", "glazed_ceramic",
            "--principled", "--forms", "osl", "--scenes", "sphere,furnace", "--samples", "4", "--resolution", "16",
            "--out", str(tmp_path / "out")]
    args += ["--truth", "--truth-paths", "64", "--truth-stride", "8"]
    done = subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    for scene in ("sphere", "furnace"):
        e = report["forms"]["osl"][scene]
        assert np.isfinite(e["principled"]["rel_rmse"])
        assert {"reference_vs_truth", "cycles_vs_truth", "principled_vs_truth", "truth_noise"} <= set(e["truth"])
    assert "Principled coat vs reference" in done.stdout
