"""``nodes.view_table.ViewTable``: a table over the view's asin(√μ) and azimuth looked up as Cycles looks up its
image."""
import math

import numpy as np
import pytest

from addon.nodes.view_table import ViewTable
from addon.reference.frames import spherical

LOWEST = math.asin(math.sqrt(0.02))


def _table(rows=5, azimuths=8, seed=0):
    return ViewTable(np.random.default_rng(seed).uniform(0.2, 2.0, (rows, azimuths, 3)), LOWEST)


def _views(angle, phi):
    """Views at asin(√μ) = ``angle``."""
    return spherical(np.sin(np.asarray(angle, dtype=float)) ** 2, np.asarray(phi, dtype=float))


def test_the_lookup_returns_the_values_at_their_texel_centres():
    t = _table()
    rows, azimuths = t.shape
    r, c = np.meshgrid(np.arange(rows - 1), np.arange(azimuths), indexing="ij")  # the last row sees along the normal
    angle = LOWEST + (0.5 * math.pi - LOWEST) * r.ravel() / (rows - 1)
    got = t.at(_views(angle, 2.0 * math.pi * c.ravel() / azimuths))
    np.testing.assert_allclose(got, t.values[r.ravel(), c.ravel()], rtol=1e-6)


def test_between_texels_it_is_bilinear_and_the_azimuth_wraps_around():
    t = _table()
    rows, azimuths = t.shape
    step = (0.5 * math.pi - LOWEST) / (rows - 1)
    angle, phi = LOWEST + 1.25 * step, 2.0 * math.pi * (azimuths - 0.5) / azimuths  # between the last and first column
    v = t.values.astype(np.float32).astype(float)
    expected = 0.75 * 0.5 * (v[1, -1] + v[1, 0]) + 0.25 * 0.5 * (v[2, -1] + v[2, 0])
    np.testing.assert_allclose(t.at(_views([angle], [phi]))[0], expected, rtol=1e-6)


def test_views_closer_to_grazing_than_the_first_row_take_its_values():
    t = _table()
    grazing = t.at(_views([0.5 * LOWEST, 1e-4], [0.0, 0.0]))
    np.testing.assert_allclose(grazing, t.values[[0, 0], [0, 0]], rtol=1e-6)


def test_the_image_name_follows_the_values():
    assert _table(seed=1).name == _table(seed=1).name != _table(seed=2).name
    assert _table().pixels().shape == (5, 9, 4)


def test_the_rows_are_dense_near_the_normal_and_near_grazing():
    """``view_table_cosines``: from the energy knots' first cosine to exactly 1, in steps of at most 4.2° of the view's
    angle near the normal (the budget of a strongly tilted flake layer changes within a few degrees of it) and of at
    most 0.016 in μ near grazing (√μ rows: 19° and 0.009), for the 32 rows that the tables have."""
    from addon.models import spongecake as model

    rows = model.VIEW_ENERGY_GRID[0]
    mu = np.array(model.view_table_cosines(rows))
    assert mu[0] == pytest.approx(model.energy_cosines()[0]) and mu[-1] == 1.0 and np.all(np.diff(mu) > 0)
    assert math.degrees(math.acos(mu[-2])) < 4.2 < math.degrees(math.acos(model.energy_cosines(rows)[-2]))
    assert mu[1] - mu[0] < 0.016


def test_a_table_over_an_input_looks_up_the_inputs_value_between_its_columns():
    """An ``Axis`` (a texture-driven input): columns at its values, uniform in log(value + offset); the lookup takes
    the input's value from the inputs, interpolates linearly in the warped value and holds the end columns beyond."""
    from addon.nodes.view_table import Axis

    axis = Axis.spaced("L1 Thickness", 0.3, 8.0, 5, offset=0.01)
    warped = np.log(np.asarray(axis.values) + 0.01)
    np.testing.assert_allclose(np.diff(warped), np.diff(warped)[0], rtol=1e-9)
    assert axis.values[0] == 0.3 and axis.values[-1] == 8.0
    assert len(axis.finer(2)) == 9 and axis.finer(2)[::2] == pytest.approx(axis.values, rel=1e-12)
    values = np.random.default_rng(3).uniform(0.2, 2.0, (5, 5, 3))
    t = ViewTable(values, LOWEST, axis)
    assert t.pixels().shape == (5, 5, 4)  # no wrapping column
    normal = _views([0.5 * math.pi], [0.0])
    v = values.astype(np.float32).astype(float)
    for c, x in enumerate(axis.values):
        np.testing.assert_allclose(t.at(normal, {axis.socket: x})[0], v[-1, c], rtol=1e-6)
    between = math.exp(0.5 * (warped[1] + warped[2])) - 0.01
    np.testing.assert_allclose(t.at(normal, {axis.socket: between})[0], 0.5 * (v[-1, 1] + v[-1, 2]), rtol=1e-6)
    np.testing.assert_allclose(t.at(normal, {axis.socket: 50.0})[0], v[-1, -1], rtol=1e-6)
    np.testing.assert_allclose(t.at(normal, {axis.socket: 0.0})[0], v[-1, 0], rtol=1e-6)
    assert t.name != ViewTable(values, LOWEST).name


def test_an_axis_of_one_value_and_a_linear_axis():
    from addon.nodes.view_table import Axis

    one = Axis.spaced("L1 Roughness", 0.4, 0.4, 9)
    assert one.values == (0.4,) and one.position(0.9) == 0.0
    linear = Axis.spaced("L1 Roughness", -0.5, 0.5, 5)
    assert linear.values == pytest.approx((-0.5, -0.25, 0.0, 0.25, 0.5))
    assert Axis.from_json(linear.to_json()) == linear


def test_a_table_over_a_colour_looks_each_channel_up_at_its_own_value():
    from addon.nodes.view_table import Axis

    axis = Axis.spaced("L1 Albedo", 0.2, 0.95, 5, offset=1.01, sign=-1.0, channels=True)
    warped = np.log(1.01 - np.asarray(axis.values))
    np.testing.assert_allclose(np.diff(warped), np.diff(warped)[0], rtol=1e-9)
    values = np.random.default_rng(4).uniform(0.2, 2.0, (5, 5, 3))
    t = ViewTable(values, LOWEST, axis)
    v = values.astype(np.float32).astype(float)
    got = t.at(_views([0.5 * math.pi], [0.0]), {axis.socket: (axis.values[0], axis.values[3], axis.values[4])})[0]
    np.testing.assert_allclose(got, [v[-1, 0, 0], v[-1, 3, 1], v[-1, 4, 2]], rtol=1e-6)
    assert Axis.from_json(axis.to_json()) == axis
