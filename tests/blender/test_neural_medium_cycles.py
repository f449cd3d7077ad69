"""Cycles renders a homogeneous medium as the numpy ground truth does (reference/neural_medium_truth.py): a sphere of
Volume Scatter + Volume Absorption with no surface, under the comparison scenes' sun. At no bounce Cycles computes
single scattering, which must equal the truth's order 1; with enough bounces its full volumetric path tracing must
equal the truth's sum of orders (the external check of the truth's orders >= 2). bpy 5.0 and 4.2.

Asserted here (24 px): order 1 means within 2% per channel and a relative RMSE within twice the truth's noise plus
2% (cloud, oil, milk); all orders (1024 bounces) within 2% per channel in the mean (cloud).
"""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from addon import presets  # noqa: E402
from addon.models import neural_medium as model  # noqa: E402
from addon.nodes.material import empty_material  # noqa: E402
from addon.operators.cycles_render import render_cycles  # noqa: E402
from addon.reference import metrics  # noqa: E402
from addon.reference import neural_medium_truth as truth  # noqa: E402
from addon.reference import scenes as S  # noqa: E402

pytestmark = pytest.mark.blender
SPHERE = S.sphere_scene(resolution=24)


def volume_material(p):
    """Cycles' own homogeneous medium for ``p``: Volume Scatter (Color = σs per scene unit, Density 1, Anisotropy g)
    plus Volume Absorption (Cycles absorbs Density × (1 − Color): Density = the largest σa), no surface."""
    mat, tree, out = empty_material("medium")
    sigma_s, sigma_a = p.per_scene_unit()
    scatter = tree.nodes.new("ShaderNodeVolumeScatter")
    scatter.inputs["Color"].default_value = (*sigma_s, 1.0)
    scatter.inputs["Density"].default_value = 1.0
    scatter.inputs["Anisotropy"].default_value = p.g
    absorb = tree.nodes.new("ShaderNodeVolumeAbsorption")
    top = max(max(sigma_a), 1e-12)
    absorb.inputs["Color"].default_value = (*[1.0 - a / top for a in sigma_a], 1.0)
    absorb.inputs["Density"].default_value = top
    both = tree.nodes.new("ShaderNodeAddShader")
    tree.links.new(scatter.outputs[0], both.inputs[0])
    tree.links.new(absorb.outputs[0], both.inputs[1])
    tree.links.new(both.outputs[0], out.inputs["Volume"])
    return mat


def _medium(name: str, scale: float):
    return model.params_from_dict({**presets.load(model.ID, name), "scale": scale})


@pytest.mark.parametrize("name, scale", [("cloud", 0.5), ("oil", 0.05), ("milk", 0.25)])
def test_single_scattering_is_the_truths_order_1(name, scale, tmp_path):
    p = _medium(name, scale)
    img, _ = render_cycles(volume_material(p), SPHERE, 64, 0, str(tmp_path / "order1.exr"))
    t = truth.render(p, truth.Sphere(), SPHERE, 512, seed=1, max_order=1)
    mask = S.scene_mask(SPHERE) & t["mask"]
    ref = t["order1"]
    noise = np.sqrt(np.mean(t["noise"]["order1"][mask] ** 2)) / ref[mask].mean()
    assert img[mask].mean(axis=0) == pytest.approx(ref[mask].mean(axis=0), rel=0.02)
    assert metrics.rel_rmse(img, ref, mask) < 2.0 * noise + 0.02  # the truth's noise plus Cycles' at 64 spp


def test_full_path_tracing_is_the_truths_sum_of_orders(tmp_path):
    p = _medium("cloud", 0.5)
    img, _ = render_cycles(volume_material(p), SPHERE, 128, 0, str(tmp_path / "all.exr"), bounces=1024)
    t = truth.render(p, truth.Sphere(), SPHERE, 512, seed=2)
    mask = S.scene_mask(SPHERE) & t["mask"]
    assert np.isfinite(img).all() and img.min() >= 0.0
    assert img[mask].mean(axis=0) == pytest.approx(t["total"][mask].mean(axis=0), rel=0.02)
    assert t["order1"][mask].mean() < 0.6 * t["total"][mask].mean()  # orders >= 2 are a large share: tested


@pytest.mark.parametrize("albedo", [0.99, 0.9])
def test_random_walk_subsurface_walks_in_the_same_medium(albedo, tmp_path):
    """``nodes.neural_medium.subsurface_material`` (the compare's random-walk SSS column) sets Cycles' random walk to
    the medium's extinction and single-scattering albedo: on a sphere 60 mean free paths across lit from the camera
    (a near half-space, where a Lambertian exit is a small approximation) it reflects what Cycles' full volumetric
    path tracing does, within 5%; Base Color = albedo instead of its inverse remap fails it at both albedos."""
    from addon.nodes import neural_medium as medium_nodes

    spec = S.sphere_scene(resolution=24, elevation_deg=90.0, sphere_segments=64, sphere_rings=32)
    p = model.params_from_dict(model.from_albedo_and_mean_free_path([albedo] * 3, [2.0 / 60.0] * 3, 0.0))
    full, _ = render_cycles(medium_nodes.new_material(p), spec, 64, 0, str(tmp_path / "full.exr"), bounces=4096)
    sss, _ = render_cycles(medium_nodes.subsurface_material(p), spec, 64, 0, str(tmp_path / "sss.exr"))
    mask = S.scene_mask(spec)
    assert sss[mask].mean() == pytest.approx(full[mask].mean(), rel=0.05)
