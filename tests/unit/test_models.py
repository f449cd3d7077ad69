"""The SpongeCake declaration: parsing, clamping with messages, refusals, presets."""
import json

import pytest

from addon import presets
from addon.models import spongecake as model
from addon.models.params import ParamError


def test_every_preset_validates_without_warnings():
    for name in presets.names(model.ID):
        v = model.validate(presets.load(model.ID, name))
        assert v.warnings == [], name
        assert 1 <= len(v.params.layers) <= model.MAX_LAYERS


def test_required_presets_exist():
    assert {"fabric", "window_shade", "plastic", "sheen", "leaf"} <= set(presets.names(model.ID))


def test_round_trip_through_dict_and_json():
    p = model.params_from_dict(presets.load(model.ID, "leaf"))
    again = model.params_from_dict(json.loads(json.dumps(p.to_dict())))
    assert again == p


def test_out_of_range_values_are_clamped_with_a_message():
    v = model.validate({"layers": [{"type": "surface", "roughness": 0.0, "thickness": -3.0,
                                    "albedo": [2.0, 0.5, float("nan")]}]})
    layer = v.params.layers[0]
    assert layer.roughness == model.MIN_FLAKE_ROUGHNESS
    assert layer.thickness == 0.0
    assert layer.albedo == (1.0, 0.5, 0.8)
    assert len(v.warnings) == 4 and all("layer 1" in w for w in v.warnings)


def test_hg_mean_cosine_is_clamped_inside_the_open_interval():
    v = model.validate({"layers": [{"type": "hg", "roughness": -1.0}]})
    assert v.params.layers[0].roughness == -model.MAX_ABS_G


def test_orientation_is_normalised_and_zero_refused_softly():
    v = model.validate({"layers": [{"orientation": [0, 0, 2]}, {"orientation": [0, 0, 0]}]})
    assert v.params.layers[0].orientation == (0.0, 0.0, 1.0)
    assert v.params.layers[1].orientation == (0.0, 0.0, 1.0) and "no direction" in v.warnings[0]


@pytest.mark.parametrize("bad, message", [
    ({"layers": []}, "1 to 4 layers"),
    ({"layers": [{}] * 5}, "1 to 4 layers"),
    ({"layers": [{"type": "velvet"}]}, "unknown value 'velvet'"),
    ({"layers": [{"colour": [1, 1, 1]}]}, "unknown parameter(s) colour"),
    ({"layers": [{"roughness": "rough"}]}, "expected a number"),
    ({"layers": [{}], "substrate": {"type": "wood"}}, "substrate"),
    ({"layers": [{}], "extra": 1}, "unknown key(s) extra"),
])
def test_bad_input_is_refused_with_a_clear_message(bad, message):
    with pytest.raises(ParamError, match=None) as e:
        model.validate(bad)
    assert message in str(e.value)


def test_unknown_preset_names_the_available_ones():
    with pytest.raises(KeyError) as e:
        presets.load(model.ID, "velvet")
    assert "fabric" in str(e.value)


def test_what_lets_light_through():
    """Opaque substrates and stacks too thick to cross block the light; a dielectric substrate refracts it through.
    A porous layer lets through what its bulk does (the grains are opaque)."""
    from addon.models import micrograin

    transmits = {n: model.params_from_dict(presets.load(model.ID, n)).transmits for n in presets.names(model.ID)}
    assert transmits == {"copper_flakes": False, "fabric": True, "leaf": True, "plastic": False, "sheen": False,
                         "thick_flakes": False, "window_shade": True}
    assert model.params_from_dict({"layers": [{}], "substrate": {"type": "dielectric"}}).transmits
    thick = {"layers": [{"thickness": model.OPAQUE_THICKNESS / 2}] * 2}
    assert not model.params_from_dict(thick).transmits
    porous = {n: micrograin.params_from_dict(presets.load(micrograin.ID, n)).transmits
              for n in ("dirt_on_glass", "dust_on_wood", "mud_on_plastic")}
    assert porous == {"dirt_on_glass": True, "dust_on_wood": False, "mud_on_plastic": False}
    over_fabric = micrograin.params_from_dict({"bulk": {"type": "spongecake", "preset": "fabric"}})
    assert over_fabric.transmits


def test_preset_metadata_is_accepted_and_ignored():
    from addon.models import MODELS

    for m, declaration in MODELS.items():
        p = declaration.default_params()
        data = {**p.to_dict(), "name": "x", "description": "y", "demo": True}
        assert declaration.validate(data).params == p, m
