"""bpy-free tests of the comparison scenes, the reference renderer, the metrics and the image writers."""
import math
import os

import numpy as np
import pytest

from addon.bake import exr
from addon.reference import metrics as M
from addon.reference import scenes as S

ALBEDO = np.array([0.8, 0.5, 0.2])


def lambert(wi, wo):
    """Lambertian reflection: albedo / pi on the upper hemisphere, 0 for transmission."""
    ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    return np.where(ok[:, None], ALBEDO / np.pi, 0.0)


def white_lambert(wi, wo):
    ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    return np.where(ok[:, None], 1.0 / np.pi, 0.0) * np.ones((1, 3))


def translucent(wi, wo):
    ok = wi[:, 2] * wo[:, 2] < 0
    return np.where(ok[:, None], 1.0 / np.pi, 0.0) * np.ones((1, 3))


def ggx_iso(alpha):
    def f(wi, wo):
        h = wi + wo
        h = h / np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-300)
        ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        a2 = alpha * alpha
        D = a2 / (np.pi * (h[:, 2] ** 2 * (a2 - 1) + 1) ** 2)

        def lam(w):
            z2 = np.maximum(w[:, 2] ** 2, 1e-300)
            return 0.5 * (-1 + np.sqrt(1 + a2 * (1 - z2) / z2))

        G = 1 / (1 + lam(wi) + lam(wo))
        v = np.where(ok, D * G / np.maximum(4 * wi[:, 2] * wo[:, 2], 1e-300), 0.0)
        return np.repeat(v[:, None], 3, 1)

    return f


# ------------------------------------------------------------------------------------------ scenes

def test_scene_validation():
    with pytest.raises(ValueError):
        S.Scene("x", "cube")
    with pytest.raises(ValueError):
        S.Scene("x", "sphere", resolution=(0, 4))
    with pytest.raises(ValueError):
        S.Sun((0, 0, 0))
    with pytest.raises(ValueError):
        S.backlit_scene(elevation_deg=10)
    assert S.Sun((0, 0, 2)).direction == (0.0, 0.0, 1.0)
    assert S.sphere_scene().camera == "orthographic" and S.furnace_scene().camera == "panorama"
    assert [s.name for s in S.default_scenes()] == ["sphere", "plane", "backlit", "furnace"]


def test_sphere_geometry_conventions():
    sc = S.sphere_scene(resolution=32)
    g = S.pixel_geometry(sc)
    n, t, b = g["n"], g["t"], g["b"]
    # row 0 = top = +y, column 0 = left = -x
    assert n[0, 16, 1] > 0.9 and n[31, 16, 1] < -0.9 and n[16, 0, 0] < -0.9 and n[16, 31, 0] > 0.9
    m = g["mask"]
    assert m.sum() > 0.8 * math.pi * 16 * 16 and not m[0, 0]
    # orthonormal right-handed frames, tangent = z x n normalised (increasing longitude)
    for v in (n, t, b):
        np.testing.assert_allclose(np.linalg.norm(v[m], axis=-1), 1, atol=1e-12)
    np.testing.assert_allclose(np.sum(n * t, -1)[m], 0, atol=1e-12)
    np.testing.assert_allclose(np.cross(t, b)[m], n[m], atol=1e-12)
    zxn = np.cross([0, 0, 1], n[m])
    np.testing.assert_allclose(t[m], zxn / np.linalg.norm(zxn, axis=-1, keepdims=True), atol=1e-12)
    # the mask keeps only pixels whose square lies inside the mesh silhouette
    assert np.all(np.hypot(n[m][:, 0], n[m][:, 1]) < math.cos(math.pi / sc.sphere_segments))


def test_panorama_geometry_conventions():
    sc = S.plane_scene(resolution=(16, 8))
    g = S.pixel_geometry(sc)
    wo = g["wo"]
    th = np.degrees(np.arccos(wo[..., 2]))
    np.testing.assert_allclose(th[:, 0], (np.arange(8) + 0.5) / 8 * 90)
    ph = np.degrees(np.arctan2(wo[..., 1], wo[..., 0])) % 360
    np.testing.assert_allclose(ph[0], (np.arange(16) + 0.5) / 16 * 360)
    assert g["mask"].all()
    assert S.plane_half_size(sc) > math.tan(math.radians(90 * (8 - 0.25) / 8))


def test_uv_sphere_mesh():
    v, f, uv = S.uv_sphere_mesh(16, 8)
    assert v.shape == (2 + 7 * 16, 3)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1, atol=1e-12)
    assert len(uv) == sum(len(p) for p in f)
    # outward winding: face normal . centroid > 0
    for p in f:
        a, b_, c = v[p[0]], v[p[1]], v[p[2]]
        assert np.dot(np.cross(b_ - a, c - a), v[list(p)].mean(0)) > 0
    assert v[:, 0].min() == pytest.approx(-1) and v[:, 1].max() == pytest.approx(1)  # centred bbox


# ------------------------------------------------------------------------------------ reference

def test_reference_lambert_sphere_analytic():
    E = 2.5
    sc = S.sphere_scene(elevation_deg=40, azimuth_deg=-70, irradiance=E, resolution=24)
    img = S.reference_image(sc, lambert)
    g = S.pixel_geometry(sc)
    L = np.asarray(sc.suns[0].direction)
    cos = np.clip(np.sum(g["n"] * L, -1), 0, None)
    expect = ALBEDO / np.pi * (cos * E)[..., None] * g["hit"][..., None]
    np.testing.assert_allclose(img, expect, atol=1e-14)
    assert np.all(img[~g["hit"]] == 0)


def test_reference_lambert_plane_and_backlit():
    sc = S.plane_scene(elevation_deg=30, irradiance=3.0, resolution=(8, 4))
    img = S.reference_image(sc, lambert)
    np.testing.assert_allclose(img, np.broadcast_to(ALBEDO / np.pi * math.sin(math.radians(30)) * 3.0, img.shape))
    bl = S.backlit_scene(elevation_deg=-60, resolution=(8, 4))
    np.testing.assert_allclose(S.reference_image(bl, lambert), 0.0)
    np.testing.assert_allclose(S.reference_image(bl, translucent), math.sin(math.radians(60)) / np.pi)


def test_sphere_blocks_light_from_below():
    sc = S.sphere_scene(elevation_deg=-20, resolution=16)  # sun below the horizon lights only the lower half
    img = S.reference_image(sc, translucent)
    np.testing.assert_allclose(img, 0.0)  # translucent needs light from behind: blocked by the sphere


def test_furnace_white_lambert_is_one():
    sc = S.furnace_scene(resolution=(16, 8))
    img = S.reference_image(sc, white_lambert, quadrature=(16, 8))
    np.testing.assert_allclose(img, 1.0, atol=1e-12)
    img = S.reference_image(sc, translucent, quadrature=(16, 8))
    np.testing.assert_allclose(img, 1.0, atol=1e-12)
    img = S.reference_image(sc, white_lambert, bsdf_albedo=lambda wo: np.full((len(wo), 3), 0.25))
    np.testing.assert_allclose(img, 0.25)


def test_directional_albedo_ggx_converged():
    """The default quadrature is converged for GGX alpha = 0.3 (compared with a 4x finer one)."""
    f = ggx_iso(0.3)
    th = np.radians([0.0, 30.0, 60.0, 80.0, 88.0])
    wo = np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], -1)
    a = S.directional_albedo(f, wo)
    b = S.directional_albedo(f, wo, quadrature=(256, 512))
    np.testing.assert_allclose(a, b, rtol=2e-4)
    # independent check: VNDF-sampled Monte Carlo (2e6 samples, sigma ~ 2e-4) of the same albedo
    np.testing.assert_allclose(a[[0, 2, 4], 0], [0.8772, 0.8220, 0.9479], atol=1e-3)
    # grazing, narrower lobes and retro-reflection: the phi nodes are packed around the incidence plane
    g = ggx_iso(0.1)
    retro = lambda wi, wo: g(wi, wo * np.array([-1.0, -1.0, 1.0]))  # noqa: E731
    wo2 = np.array([[np.sin(np.radians(89.0)), 0.0, np.cos(np.radians(89.0))]])
    for f2 in (g, retro):
        np.testing.assert_allclose(S.directional_albedo(f2, wo2), S.directional_albedo(f2, wo2, (512, 2048)),
                                   rtol=1e-3)


def test_lobe_view():
    img = S.lobe_view(lambert, 9, 36)
    assert img.shape == (9, 36, 3)
    ti = (np.arange(9) + 0.5) / 9 * 90
    p = -180 + (np.arange(36) + 0.5) / 36 * 360
    refl = np.abs(p) < 90
    expect = ALBEDO / np.pi * np.cos(np.radians(ti))[:, None, None] * refl[None, :, None]
    np.testing.assert_allclose(img, expect, atol=1e-14)
    g = S.lobe_view(ggx_iso(0.1), 18, 72, cosine="none")
    r = 9  # ti = 47.5 deg: the peak is at the mirror column p = -ti
    assert abs(p[np.argmax(g[r, :, 0])] * 0 + (-180 + (np.argmax(g[r, :, 0]) + 0.5) / 72 * 360) + 47.5) <= 5


# -------------------------------------------------------------------------------------- metrics

def test_metrics_on_synthetic_images():
    rng = np.random.default_rng(1)
    ref = rng.uniform(0.5, 1.5, (8, 10, 3))
    cyc = ref.copy()
    cyc[2, 3] += [0.1, 0.0, -0.3]
    cyc[5, 7] += 0.2
    mask = np.ones((8, 10), bool)
    e = np.zeros_like(ref)
    e[2, 3] = [0.1, 0.0, -0.3]
    e[5, 7] = 0.2
    assert M.rmse(cyc, ref, mask) == pytest.approx(np.sqrt(np.mean(e ** 2)))
    assert M.rel_rmse(cyc, ref, mask) == pytest.approx(np.sqrt(np.mean(e ** 2)) / ref.mean())
    assert M.max_abs_error(cyc, ref) == pytest.approx(0.3)
    w = M.worst_pixels(cyc, ref, mask, k=2)
    assert [(r, c) for r, c, _, _ in w] == [(2, 3), (5, 7)]
    assert w[0][2] == pytest.approx(tuple(cyc[2, 3])) and w[0][3] == pytest.approx(tuple(ref[2, 3]))
    # masking out the worst pixel removes it from every metric
    mask[2, 3] = False
    assert M.max_abs_error(cyc, ref, mask) == pytest.approx(0.2)
    assert M.worst_pixels(cyc, ref, mask, k=1)[0][:2] == (5, 7)
    assert M.rmse(ref, ref, mask) == 0.0
    s = M.summary(cyc, ref, mask, k=3)
    assert s["pixels"] == 79 and len(s["worst_pixels"]) == 3
    with pytest.raises(ValueError):
        M.rmse(ref, ref[:, :5])


def test_heat_map_tonemap_side_by_side():
    ref = np.full((4, 5, 3), 0.5)
    cyc = ref.copy()
    cyc[1, 1] += 0.25  # = 50% of the mean: full scale by default
    cyc[2, 2] -= 0.05  # = 10% of the mean: a fifth of the scale, between the first two stops
    mask = np.ones((4, 5), bool)
    mask[3, 4] = False
    assert M.HEAT_SCALE == 0.5
    heat, vmax = M.heat_map(cyc, ref, mask)
    assert vmax == pytest.approx(0.25)
    np.testing.assert_allclose(heat[1, 1], M.HEAT_STOPS[-1][1])
    np.testing.assert_allclose(heat[2, 2], 0.8 * np.array(M.HEAT_STOPS[1][1]))
    np.testing.assert_allclose(heat[0, 0], 0.0)
    np.testing.assert_allclose(heat[3, 4], M.MASKED_GREY)
    t = M.tonemap(np.array([[[0.0, 0.5, 1.0], [2.0, np.nan, 0.0031308]]]), exposure=0)
    assert t.dtype == np.uint8 and t[0, 0].tolist() == [0, 188, 255] and t[0, 1, 0] == 255 and t[0, 1, 1] == 0
    assert M.tonemap(np.full((1, 1, 3), 0.25), exposure=2)[0, 0, 0] == 255
    assert M.auto_exposure(np.full((3, 3, 3), 4.0)) == pytest.approx(-2.0)
    pic, info = M.side_by_side(cyc, ref, mask, exposure=1.0, gap=2)
    assert pic.shape == (4, 3 * 5 + 4, 3) and pic.dtype == np.uint8
    assert info == {"exposure": 1.0, "heat_vmax": pytest.approx(0.25)}
    np.testing.assert_array_equal(pic[:, :5], M.tonemap(cyc, 1.0))
    np.testing.assert_array_equal(pic[:, 7:12], M.tonemap(ref, 1.0))


# ------------------------------------------------------------------------------------ image I/O

def test_exr_round_trip_and_row_order(tmp_path):
    img = np.zeros((6, 9, 3))
    img[0, 0] = [1.0, 2.0, 3.0]  # top-left
    img[5, 8] = [-1.0, 1e6, 0.125]
    p = tmp_path / "a.exr"
    exr.write_exr(p, img)
    back = exr.read_exr(p)
    assert back.shape == (6, 9, 3) and back.dtype == np.float64
    np.testing.assert_array_equal(back, img.astype(np.float32))
    rgba = np.random.default_rng(0).random((3, 4, 4))
    exr.write_exr(p, rgba)  # overwrite atomically
    np.testing.assert_array_equal(exr.read_exr(p), rgba.astype(np.float32))
    np.testing.assert_array_equal(exr.read_exr(p, "RGB"), rgba[..., :3].astype(np.float32))
    assert sorted(os.listdir(tmp_path)) == ["a.exr"]
    with pytest.raises(ValueError):
        exr.write_exr(tmp_path / "b.exr", np.zeros((2, 2, 2)))
    assert sorted(os.listdir(tmp_path)) == ["a.exr"]


def test_png_round_trip(tmp_path):
    rng = np.random.default_rng(2)
    for shape in [(5, 7, 3), (4, 3, 4), (6, 2)]:
        img = rng.integers(0, 256, shape, dtype=np.uint8)
        p = tmp_path / "a.png"
        exr.write_png(p, img)
        back = exr.read_png(p)
        np.testing.assert_array_equal(back.reshape(img.shape), img)
    with pytest.raises(ValueError):
        exr.write_png(tmp_path / "f.png", np.zeros((2, 2, 3)))  # float: tone-map first
    assert sorted(os.listdir(tmp_path)) == ["a.png"]


def test_png_reader_handles_all_filters(tmp_path):
    """A PNG written with Sub/Up/Average/Paeth rows (as other encoders do) decodes exactly."""
    import struct
    import zlib

    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (5, 4, 3), dtype=np.uint8).astype(np.int32)
    h, w, c = img.shape
    rows = []
    prev = np.zeros(w * c, np.int32)
    for y in range(h):
        line = img[y].reshape(-1)
        ft = y % 5
        left = np.concatenate([np.zeros(c, np.int32), line[:-c]])
        ul = np.concatenate([np.zeros(c, np.int32), prev[:-c]])
        if ft == 0:
            pred = np.zeros_like(line)
        elif ft == 1:
            pred = left
        elif ft == 2:
            pred = prev
        elif ft == 3:
            pred = (left + prev) >> 1
        else:
            pa, pb, pc = np.abs(prev - ul), np.abs(left - ul), np.abs(left + prev - 2 * ul)
            pred = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, prev, ul))
        rows.append(bytes([ft]) + ((line - pred) & 255).astype(np.uint8).tobytes())
        prev = line

    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))

    data = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"".join(rows))) + chunk(b"IEND", b""))
    p = tmp_path / "f.png"
    p.write_bytes(data)
    np.testing.assert_array_equal(exr.read_png(p), img.astype(np.uint8))


def test_atomic_write_leaves_no_temp_file(tmp_path):
    target = tmp_path / "x.bin"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with exr.atomic_path(target) as tmp:
            with open(tmp, "wb") as f:
                f.write(b"half")
            raise RuntimeError("boom")
    assert target.read_bytes() == b"old"
    assert sorted(os.listdir(tmp_path)) == ["x.bin"]
    with exr.atomic_path(target) as tmp:
        assert os.path.dirname(tmp) == str(tmp_path) and tmp.endswith(".bin")
        with open(tmp, "wb") as f:
            f.write(b"new")
    assert target.read_bytes() == b"new"
    assert sorted(os.listdir(tmp_path)) == ["x.bin"]


def _frames_of(scene):
    """A ``views`` scene's frames from another scene's pixel geometry (its masked pixels, row by row)."""
    g = S.pixel_geometry(scene)
    m = g["mask"]
    return np.concatenate([g["n"][m], g["t"][m], g["b"][m], g["wo"][m]], axis=1), m


@pytest.mark.parametrize("bsdf", [lambert, translucent, ggx_iso(0.3)])
def test_a_camera_view_renders_the_points_it_is_given_as_the_panoramas_do(bsdf):
    """The points of the plane and furnace panoramas, given as the frames of a camera's view, render as there: under
    the key light (the plane's sun) and in the white environment (the furnace)."""
    plane = S.plane_scene(resolution=(16, 8))
    frames, mask = _frames_of(plane)
    key, furnace = S.view_scenes(frames, plane.suns[0].direction)
    assert (key.kind, furnace.kind) == (S.VIEWS, S.VIEWS) and key.resolution == (len(frames), 1)
    assert np.allclose(S.reference_image(key, bsdf)[0], S.reference_image(plane, bsdf)[mask], atol=1e-12)
    albedo = S.reference_image(furnace, bsdf)[0]
    assert np.allclose(albedo, S.reference_image(S.furnace_scene(resolution=(16, 8)), bsdf)[mask], atol=1e-12)
    assert S.scene_mask(key).all()


def test_a_camera_view_in_another_frame_gives_the_same_light():
    """The sphere's points (a frame turned with every pixel) lit from its sun: a rotation-invariant BSDF gives the
    same values, whatever the world frame (the key light turned with them)."""
    frames, _ = _frames_of(S.sphere_scene(resolution=12))
    rot = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])
    sun = S.sphere_scene().suns[0].direction
    turned = (frames.reshape(-1, 4, 3) @ rot.T).reshape(-1, 12)
    a, b = (S.reference_image(S.view_scenes(f, s)[0], lambert) for f, s in ((frames, sun), (turned, rot @ sun)))
    assert np.allclose(a, b, atol=1e-12) and a.max() > 0.1


def test_frames_go_with_the_views_kind_only():
    with pytest.raises(ValueError, match="frames"):
        S.Scene("x", S.VIEWS, (1, 1))
    with pytest.raises(ValueError, match="frames"):
        S.Scene("x", "plane", (1, 1), frames=((0.0,) * 12,))
