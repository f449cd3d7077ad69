"""The neural medium's material and bake in Cycles (issue 13, part 4): the surface adds exactly the light stored in the
mesh, once (front faces only), on top of Cycles' own single scattering; a bake of the comparison sphere renders the
gather's prediction; bad input is refused before anything is written. bpy 5.0 and 4.2.

The tables here are Monte Carlo tables of the cloud's green channel (``training.medium_tracer``), not the shipped
networks: these tests check the wiring, not the networks (tests/unit/test_medium_networks.py does)."""
import json

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
import bmesh  # noqa: E402 - after bpy

from addon import presets  # noqa: E402
from addon.bake import neural_medium as nb  # noqa: E402
from addon.models import neural_medium as model  # noqa: E402
from addon.nodes import neural_medium as medium_nodes  # noqa: E402
from addon.operators import medium_bake  # noqa: E402
from addon.operators.cycles_render import render_cycles  # noqa: E402
from addon.reference import neural_medium as nm  # noqa: E402
from addon.reference import neural_medium_truth as truth  # noqa: E402
from addon.reference import scenes as S  # noqa: E402
from training import medium_tracer as mt  # noqa: E402

pytestmark = pytest.mark.blender
SPHERE = S.sphere_scene(resolution=24, sphere_segments=64, sphere_rings=32)
CLOUD = model.params_from_dict({**presets.load(model.ID, "cloud"), "scale": 0.5})  # 4.4 mfp across, grey
GREY = model.params_from_dict({**CLOUD.to_dict(), "sigma_s": [CLOUD.sigma_s[1]] * 3, "sigma_a": [CLOUD.sigma_a[1]] * 3})


@pytest.fixture(scope="module")
def tables():
    grid = mt.default_grid()
    r = mt.simulate(GREY.albedo[1], GREY.g, grid, mt.Settings(photons=40_000, double_photons=400_000, batches=4),
                    seed=[3])
    edges = (np.asarray(grid.rho_edges), np.asarray(grid.z_edges), grid.theta_centres(), grid.phi_centres())
    return [{kind: nm.Table(r[kind], *edges) for kind in nm.KINDS}] * 3


def test_the_surface_adds_the_stored_light_once(tmp_path):
    """Constant coefficients c0 + cz (the camera looks down -z, so w = +z): the render gains exactly that on the
    sphere (front faces; the back face seen from inside adds nothing) and nothing around it."""
    mat = medium_nodes.new_material(GREY)
    c0, cz = np.array([0.02, 0.05, 0.08]), np.array([0.01, 0.01, 0.01])

    def store(scene, obj):
        c = np.zeros((len(obj.data.vertices), 4, 3))
        c[:, 0], c[:, 3] = c0, cz
        medium_nodes.store(obj.data, c)

    plain, _ = render_cycles(mat, SPHERE, 64, 0, str(tmp_path / "ss.exr"))
    baked, _ = render_cycles(mat, SPHERE, 64, 0, str(tmp_path / "ss_bake.exr"), prepare=store)
    inside = S.scene_mask(SPHERE)
    origins, directions = truth.camera_rays(SPHERE, truth.Sphere())
    far = ~np.isfinite(truth.Sphere(radius=1.1).interval(origins, directions)[0]).reshape(24, 24)
    gained = (baked - plain)[inside].mean(axis=0)
    np.testing.assert_allclose(gained, c0 + cz, rtol=0.03)
    assert np.abs(baked - plain)[far].max() < 1e-6


def test_a_bake_of_the_sphere_renders_the_gather(tables, tmp_path):
    """Baked from the temporary scene's own sun into its sphere mesh, the render's gain over single scattering is
    the gather along the camera rays into the analytic sphere (the bake's reference): within 5% in the mean and 15%
    relative RMSE (per-vertex interpolation of a 64 x 32 sphere, the linear fit in the direction, Cycles' noise)."""
    mat = medium_nodes.new_material(GREY)
    records = []

    def bake(scene, obj):
        scene.view_layers[0].update()  # the new lamp's matrix
        depsgraph = scene.view_layers[0].depsgraph
        result = medium_bake.run(obj, scene, depsgraph, GREY, nb.Settings(cells=12, steps=8), tables=tables)
        records.append(result["record"])

    plain, _ = render_cycles(mat, SPHERE, 64, 0, str(tmp_path / "ss.exr"))
    baked, _ = render_cycles(mat, SPHERE, 64, 0, str(tmp_path / "ss_bake.exr"), prepare=bake)
    assert records and records[0]["points"] == 64 * 31 + 2 and records[0]["beams"] > 50
    assert records[0]["gathered"] < 0.5 * records[0]["points"]  # half a mean free path apart
    origins, directions = truth.camera_rays(SPHERE, truth.Sphere())
    beams = nm.Beams.join(nm.sun_beams(truth.Sphere(), sun, 12) for sun in SPHERE.suns)
    g = nm.gather(tables[1], GREY.mean_free_path[1], truth.Sphere(), beams, origins, directions, steps=8,
                  images=nm.boundary(GREY.albedo[1], GREY.g))
    expected = (g["double"] + g["multiple"]).reshape(24, 24)
    inside = S.scene_mask(SPHERE) & (expected > 0.0)
    gain = (baked - plain)[..., 1]
    assert np.isfinite(baked).all() and baked.min() >= 0.0
    assert gain[inside].mean() == pytest.approx(expected[inside].mean(), rel=0.05)
    assert np.sqrt(np.mean((gain[inside] - expected[inside]) ** 2)) < 0.15 * expected[inside].mean()


def _scene_with(obj_mesh, lamps=(("SUN", (0.0, 0.0, 5.0)),)):
    scene = bpy.data.scenes.new("bake test")
    obj = bpy.data.objects.new("medium", obj_mesh)
    scene.collection.objects.link(obj)
    for kind, location in lamps:
        lamp = bpy.data.objects.new(kind, bpy.data.lights.new(kind, type=kind))
        lamp.location = location
        scene.collection.objects.link(lamp)
    return scene, obj


def _sphere_mesh(segments=16, rings=8):
    verts, faces, _ = S.uv_sphere_mesh(segments, rings)
    mesh = bpy.data.meshes.new("ball")
    mesh.from_pydata(verts.tolist(), [], faces)
    return mesh


def test_bad_input_is_refused_before_any_work():
    plane = bpy.data.meshes.new("plane")
    plane.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [], [(0, 1, 2, 3)])
    scene, obj = _scene_with(plane)
    with pytest.raises(medium_bake.BakeError, match="not closed"):
        next(medium_bake.bake_steps(obj, scene, None, GREY, nb.Settings()))
    scene, obj = _scene_with(_sphere_mesh(), lamps=())
    scene.world = bpy.data.worlds.new("sky")
    scene.world.color = (0.2, 0.3, 0.5)  # 4.2: a new world's nodes are off; 5.0: its Background node lights
    with pytest.raises(medium_bake.BakeError, match=r"no lamp lights the object.*the world \(sky\) lights the "
                                                    r"object and is not baked"):
        next(medium_bake.bake_steps(obj, scene, None, GREY, nb.Settings()))
    scene, obj = _scene_with(_sphere_mesh(), lamps=(("POINT", (0.0, 0.0, 0.2)),))
    scene.view_layers[0].update()
    with pytest.raises(medium_bake.BakeError, match="inside"):
        next(medium_bake.bake_steps(obj, scene, scene.view_layers[0].depsgraph, GREY, nb.Settings()))
    scene, obj = _scene_with(_sphere_mesh(), lamps=(("AREA", (0.0, 0.0, 0.9)),))  # inside the bounds
    scene.view_layers[0].update()
    with pytest.raises(medium_bake.BakeError, match="inside"):
        next(medium_bake.bake_steps(obj, scene, scene.view_layers[0].depsgraph, GREY, nb.Settings()))
    assert medium_bake.mesh_problem(bpy.data.objects.new("empty", None)).startswith("select a mesh")
    assert not medium_nodes.has_bake(obj.data)  # nothing half-written


def test_other_objects_shadow_the_beams_and_the_object_itself_does_not():
    """A beam whose way back to the sun crosses another object is dropped; one whose way back crosses the medium's
    own mesh (here: entries placed on the far side of the sphere) is kept, since the object is the medium."""
    scene, obj = _scene_with(_sphere_mesh())
    lamp = {"type": "SUN"}
    down = np.array([[0.0, 0.0, -1.0]] * 2)
    far_side = nm.Beams(np.array([[0.0, 0.0, -1.0], [0.3, 0.0, -0.9]]), down, np.ones(2))
    scene.view_layers[0].update()
    assert len(medium_bake.unshadowed(far_side, lamp, scene, scene.view_layers[0].depsgraph, obj)) == 2
    roof = bpy.data.meshes.new("roof")
    roof.from_pydata([(-2, -2, 3), (2, -2, 3), (2, 0, 3), (-2, 0, 3)], [], [(0, 1, 2, 3)])  # over y < 0
    scene.collection.objects.link(bpy.data.objects.new("roof", roof))
    scene.view_layers[0].update()
    top = nm.Beams(np.array([[0.0, -0.5, 0.85], [0.0, 0.5, 0.85]]), down, np.ones(2))
    kept = medium_bake.unshadowed(top, lamp, scene, scene.view_layers[0].depsgraph, obj)
    assert len(kept) == 1 and kept.entries[0, 1] == 0.5


@pytest.mark.parametrize("shape", ["box", "torus", "suzanne"])
def test_the_comparison_meshes_are_closed_and_in_view(shape):
    """compare-medium's meshes: the bake accepts them (Suzanne as Blender makes her is open at the eyes), and they lie
    within the comparison camera's view of the unit sphere."""
    from addon.operators import medium_compare

    verts, faces = medium_compare.MESHES[shape]()
    mesh = bpy.data.meshes.new(shape)
    mesh.from_pydata(verts, [], faces)
    assert medium_bake.mesh_problem(bpy.data.objects.new(shape, mesh)) is None
    assert np.abs(np.asarray(verts)[:, :2]).max() < S.ortho_extent(SPHERE)[0]
    if shape == "suzanne":
        monkey = bpy.data.meshes.new("monkey")
        bm = bmesh.new()
        bmesh.ops.create_monkey(bm)
        bm.to_mesh(monkey)
        bm.free()
        assert "not closed" in medium_bake.mesh_problem(bpy.data.objects.new("monkey", monkey))


def test_the_bake_is_stored_per_mesh_and_goes_stale(tables):
    scene, obj = _scene_with(_sphere_mesh())
    mat = medium_nodes.new_material(GREY)
    obj.data.materials.append(mat)
    assert medium_bake.bake_state(obj, scene)[0] == "none"
    scene.view_layers[0].update()
    depsgraph = scene.view_layers[0].depsgraph
    medium_bake.run(obj, scene, depsgraph, GREY, nb.Settings(cells=4, steps=4), tables=tables)
    assert medium_nodes.has_bake(obj.data) and json.loads(obj[medium_bake.PROPERTY])["points"] == 16 * 7 + 2
    assert medium_bake.bake_state(obj, scene)[0] == "baked"
    lamp = next(o for o in scene.objects if o.type == "LIGHT")
    lamp.rotation_euler[0] = 0.3
    scene.view_layers[0].update()
    assert medium_bake.bake_state(obj, scene)[0] == "stale"
    lamp.rotation_euler[0] = 0.0
    scene.view_layers[0].update()
    assert medium_bake.bake_state(obj, scene)[0] == "baked"
    mat.node_tree.nodes[medium_nodes.SCATTER].inputs["Anisotropy"].default_value = 0.5
    assert medium_bake.bake_state(obj, scene)[0] == "stale"


def test_an_area_lamp_is_baked_and_its_size_makes_the_bake_stale(tables):
    """A square area lamp above the sphere: the bake has beams and light; resizing the lamp makes it stale.
    (That a far area lamp lights the medium as a sun does: tests/unit/test_neural_medium_gather.py.)"""
    scene, obj = _scene_with(_sphere_mesh(), lamps=(("AREA", (0.0, 0.0, 4.0)),))
    obj.data.materials.append(medium_nodes.new_material(GREY))
    lamp = next(o for o in scene.objects if o.type == "LIGHT")
    lamp.data.energy, lamp.data.size = 500.0, 2.0
    scene.view_layers[0].update()
    result = medium_bake.run(obj, scene, scene.view_layers[0].depsgraph, GREY, nb.Settings(cells=4, steps=4),
                             tables=tables)
    c0 = result["coefficients"][:, 0, :]
    assert result["record"]["beams"] > 0 and np.isfinite(c0).all() and c0.max() > 0.0
    assert medium_bake.bake_state(obj, scene)[0] == "baked"
    lamp.data.size = 1.0
    assert medium_bake.bake_state(obj, scene)[0] == "stale"


def test_the_material_reads_back_the_medium_it_was_made_from():
    p = model.params_from_dict(presets.load(model.ID, "milk"))
    mat = medium_nodes.new_material(p)
    back = medium_nodes.current_params(mat)
    np.testing.assert_allclose(back.sigma_s, p.sigma_s, rtol=1e-6)
    np.testing.assert_allclose(back.sigma_a, p.sigma_a, rtol=1e-5)
    assert back.g == pytest.approx(p.g) and back.scale == p.scale


def test_the_bake_operator_and_the_cli_use_the_shipped_networks(registered, tmp_path):
    """The whole path with the shipped networks: Add, Bake Scattering (execute, as a script runs it), then
    ``bake-medium`` on a saved file: finite, non-negative light on the lit side, the file written once."""
    from addon import cli

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_uv_sphere_add(segments=16, ring_count=8)
    ball = bpy.context.active_object
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", type="SUN"))
    bpy.context.scene.collection.objects.link(sun)
    bpy.context.view_layer.update()
    assert bpy.ops.lamina.add_neural_medium(preset="cloud", scale=0.5) == {"FINISHED"}
    assert bpy.ops.lamina.bake_medium(cells=6, steps=4) == {"FINISHED"}
    c = np.array([tuple(v.vector) for v in ball.data.attributes[medium_nodes.ATTRIBUTES[0]].data])
    assert np.isfinite(c).all() and c.max() > 0.0
    assert medium_bake.bake_state(ball, bpy.context.scene)[0] == "baked"
    source, out, name = tmp_path / "in.blend", tmp_path / "out.blend", ball.name
    bpy.ops.wm.save_as_mainfile(filepath=str(source))
    assert cli.main(["bake-medium", "--blend", str(source), "--object", name, "--preset", "milk", "--scale",
                     "0.05", "--cells", "4", "--steps", "4", "--out", str(out)]) == 0
    bpy.ops.wm.open_mainfile(filepath=str(out))
    baked = bpy.data.objects[name]
    assert medium_nodes.is_medium(baked.material_slots[0].material) and medium_nodes.has_bake(baked.data)
    assert medium_nodes.current_params(baked.material_slots[0].material).g == pytest.approx(0.7)  # the milk
    assert cli.main(["bake-medium", "--blend", str(source), "--object", name, "--out", str(out)]) == 2  # exists


def test_compare_medium_writes_its_report_and_the_bake_closes_most_of_the_gap(tables, tmp_path, monkeypatch):
    """The comparison (``lamina compare-medium``, the bench) on a small sphere: four Cycles forms against the numpy
    truth, pictures and report.json; single scattering alone misses the orders >= 2 that the bake adds."""
    from addon.operators import medium_compare

    monkeypatch.setattr(medium_compare, "CACHE", tmp_path / "cache")
    monkeypatch.setattr(nb, "channel_tables", lambda p: tables)
    sizes = medium_compare.Sizes(samples=16, resolution=16, truth_paths=128, full_bounces=256,
                                 bake=nb.Settings(cells=8, steps=6), equal_error_samples=64)
    report = medium_compare.compare_medium(GREY, sizes, str(tmp_path), label="cloud")
    forms = report["forms"]
    assert set(forms) == {medium_compare.SINGLE, medium_compare.BAKED, medium_compare.FULL, medium_compare.SUBSURFACE}
    assert all(f["finite"] and f["min"] >= 0.0 for f in forms.values())
    assert forms[medium_compare.SINGLE]["energy_error"] < -0.2  # orders >= 2 are missing
    assert abs(forms[medium_compare.BAKED]["energy_error"]) < 0.5 * abs(forms[medium_compare.SINGLE]["energy_error"])
    assert abs(forms[medium_compare.FULL]["energy_error"]) < 0.1  # Cycles' own path tracing agrees with the truth
    assert (tmp_path / "comparison.png").exists() and json.loads((tmp_path / "report.json").read_text())["bake"]
    assert len(list((tmp_path / "cache").glob("*.npz"))) == 1  # the truth, cached
    equal = report["full_at_bake_error"]  # full path tracing at 32, then 64 samples until the bake's error
    assert equal["samples"] in (32, 64) and equal["target"] == pytest.approx(forms[medium_compare.BAKED]["rel_rmse"])
    assert equal["reached"] == (equal["rel_rmse"] <= equal["target"]) and (equal["reached"] or equal["samples"] == 64)


@pytest.mark.parametrize("kind", ["POINT", "AREA"])
def test_a_lamp_of_power_p_has_the_intensity_the_bake_assumes(kind, tmp_path):
    """The bake's point and spot lamps radiate P / (4 pi) W/sr, its area lamps are one-sided Lambertian emitters of
    total power P, radiance P / (pi A) (``medium_bake.lamp_beams``): a white Lambertian top of the sphere D below
    the lamp shows (1 / pi) E, E the irradiance: I / D^2 for a point lamp of radius 0, and for a 2 x 2 square lamp
    the integral of L cos cos / r^2 over it (midpoint rule)."""
    from addon.nodes.material import empty_material

    mat, tree, out = empty_material("white")
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    tree.links.new(diffuse.outputs[0], out.inputs["Surface"])
    power, distance, side = 1000.0, 6.0, 2.0
    lamps = []

    def lamp(scene, obj):
        for o in scene.objects:
            if o.type == "LIGHT":
                o.data.energy = 0.0
        light = bpy.data.lights.new("lamp", type=kind)
        light.energy = power
        if kind == "POINT":
            light.shadow_soft_size = 0.0
        else:
            light.shape, light.size = "SQUARE", side
        ob = bpy.data.objects.new("lamp", light)
        ob.location = (0.0, 0.0, 1.0 + distance)
        scene.collection.objects.link(ob)
        lamps.append(ob)

    spec = S.sphere_scene(resolution=24)
    try:
        img, _ = render_cycles(mat, spec, 256, 0, str(tmp_path / "lamp.exr"), prepare=lamp)
    finally:
        for ob in lamps:
            data = ob.data
            bpy.data.objects.remove(ob)
            bpy.data.lights.remove(data)
    centre = img[11:13, 11:13].mean(axis=(0, 1))
    if kind == "POINT":
        irradiance = power / (4.0 * np.pi) / distance ** 2
    else:
        u = (np.arange(400) + 0.5) / 400 * side - 0.5 * side
        x, y = np.meshgrid(u, u)
        irradiance = power / (np.pi * side ** 2) * np.mean(distance ** 2 / (distance ** 2 + x * x + y * y) ** 2) \
            * side ** 2
    np.testing.assert_allclose(centre, irradiance / np.pi, rtol=0.02)
