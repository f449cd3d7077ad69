"""Cycles' random-walk subsurface scattering as a medium (``nodes/subsurface_np.py``, bpy-free): Cycles' remap from
Base Color to single-scattering albedo rises monotonically on [0, 1] (so the bisection finds the one colour), the
inversion round-trips, and the Principled settings give back the medium's extinction. The render itself is checked
against Cycles' volume in tests/blender/test_neural_medium_cycles.py."""
import numpy as np
import pytest

from addon.nodes import subsurface_np as sss

GS = (0.0, 0.3, 0.7, 0.9)


@pytest.mark.parametrize("g", GS)
def test_the_remap_rises_from_0_to_about_1(g):
    colors = np.linspace(0.0, 1.0, 2001)
    albedo = sss.single_scattering_albedo(colors, g)
    assert albedo[0] == 0.0 and albedo[-1] > 0.99
    rising = albedo < sss.MAX_ALBEDO  # above, the clamp
    assert np.all(np.diff(albedo) >= 0.0) and np.all(np.diff(albedo[rising]) > 0.0)
    assert np.all((albedo >= 0.0) & (albedo <= sss.MAX_ALBEDO))


@pytest.mark.parametrize("g", GS)
def test_base_color_inverts_the_remap(g):
    albedo = np.array([0.0, 0.05, 0.2, 0.5, 0.9, 0.99, 0.999])
    color = sss.base_color(albedo, g)
    assert np.all((color >= 0.0) & (color <= 1.0))
    np.testing.assert_allclose(sss.single_scattering_albedo(color, g), albedo, atol=1e-9)
    assert np.all(np.diff(color) > 0.0)


def test_a_colour_below_its_albedo_is_what_makes_the_remap_useful():
    """The remap is not the identity: a half-space of single-scattering albedo 0.99 looks about 0.7 grey."""
    assert 0.6 < float(sss.base_color(0.99, 0.0)) < 0.8


def test_settings_give_back_the_extinction_and_say_what_they_clamp():
    sigma_t, albedo = np.array([2.0, 4.0, 8.0]), np.array([0.99, 0.9, 0.1])
    s = sss.subsurface_settings(sigma_t, albedo, 0.95)
    g = s["inputs"]["Subsurface Anisotropy"]
    assert g == sss.MAX_ANISOTROPY
    radius = np.array(s["inputs"]["Subsurface Radius"])
    np.testing.assert_allclose(1.0 / (radius * (1.0 - g)), sigma_t)
    assert len(s["notes"]) == 2 and "0.9" in s["notes"][0] and "0.2" in s["notes"][1]
    assert sss.subsurface_settings(sigma_t, [0.5] * 3, 0.3)["notes"] == []
    assert sss.subsurface_settings(sigma_t, [0.5] * 3, -0.5)["inputs"]["Subsurface Anisotropy"] == 0.0
