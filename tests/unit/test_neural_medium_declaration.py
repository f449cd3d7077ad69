"""The neural medium's declaration: the dict API of docs/api.md, its refusals and clamps, the derived albedo and
mean free path, and the presets after the paper's Table 1."""
import math

import pytest

from addon import presets
from addon.models import neural_medium as model
from addon.models.params import ParamError

TABLE_1 = {"milk": ((0.999,) * 3, (0.84, 0.75, 0.68), 0.7), "oil": ((0.398, 0.453, 0.032), (9.71, 11.63, 2.74), 0.9),
           "cloud": ((0.909,) * 3, (0.909,) * 3, 0.0)}


@pytest.mark.parametrize("name", TABLE_1)
def test_presets_reproduce_the_papers_albedo_and_mean_free_path(name):
    albedo, mfp, g = TABLE_1[name]
    p = model.params_from_dict(presets.load(model.ID, name))
    assert p.albedo == pytest.approx(albedo, abs=2e-6) and p.mean_free_path == pytest.approx(mfp, rel=1e-5)
    assert p.g == g and p.scale == 1.0


@pytest.mark.parametrize("name", presets.names(model.ID))
def test_every_preset_validates_without_warnings_and_round_trips(name):
    v = model.validate(presets.load(model.ID, name))
    assert v.warnings == [] and model.params_from_dict(v.params.to_dict()) == v.params


def test_scale_is_scene_units_per_unit_length():
    p = model.params_from_dict({"sigma_s": [0.5, 1.0, 2.0], "sigma_a": [0.5, 0.0, 2.0], "scale": 0.1})
    assert p.mean_free_path == pytest.approx((0.1, 0.1, 0.025))
    sigma_s, sigma_a = p.per_scene_unit()
    assert sigma_s == pytest.approx((5.0, 10.0, 20.0)) and sigma_a == pytest.approx((5.0, 0.0, 20.0))


@pytest.mark.parametrize("data, message", [
    ({"sigma_s": 0.0, "sigma_a": 0.0}, "is 0 in channel(s) R, G, B"),
    ({"sigma_s": [1.0, 0.0, 1.0], "sigma_a": [0.0, 0.0, 0.0]}, "is 0 in channel(s) G"),
    ({"density": 1.0}, "unknown parameter(s) density"),
    ({"g": "forward"}, "g: expected a number"),
    ([1, 2], "expected a dict"),
])
def test_bad_input_is_refused_with_one_message(data, message):
    with pytest.raises(ParamError, match=None) as e:
        model.validate(data)
    assert message in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("data, field", [({"g": 1.0}, "g"), ({"g": -2.0}, "g"), ({"scale": 0.0}, "scale"),
                                          ({"sigma_s": [math.nan, 1.0, 1.0]}, "sigma_s[0]"),
                                          ({"sigma_a": [-1.0, 0.1, 0.1]}, "sigma_a[0]")])
def test_out_of_range_values_are_clamped_with_a_warning(data, field):
    v = model.validate(data)
    assert len(v.warnings) == 1 and f"{field}:" in v.warnings[0]
    assert all(math.isfinite(x) for x in (*v.params.sigma_s, *v.params.sigma_a, v.params.g, v.params.scale))
    assert -model.MAX_G <= v.params.g <= model.MAX_G and v.params.scale > 0


@pytest.mark.parametrize("albedo", [0.0, 1.0])
def test_albedo_0_and_1_are_valid_media(albedo):
    p = model.params_from_dict(model.from_albedo_and_mean_free_path((albedo,) * 3, (1.0,) * 3, 0.0))
    assert p.albedo == pytest.approx((albedo,) * 3) and p.sigma_t == pytest.approx((1.0,) * 3)
