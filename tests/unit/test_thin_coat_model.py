"""The Thin Coat declaration as the UI, the CLI and the Python API see it: presets, clamping with messages,
refusals, roughness ↔ κ, whole-number bounces; and the thin coat as a micrograin bulk (its sampler is built from
the view: the porous layer's sampler must hand it the held direction as its view and exchange its pdf's
arguments, ``reference.micrograin.samples_from_view``)."""
import json
import math
import zlib

import numpy as np
import pytest

from addon import presets
from addon.models import MODELS
from addon.models import micrograin
from addon.models import thin_coat as model
from addon.models.params import ParamError
from addon.reference import micrograin as mg
from addon.reference import scenes
from addon.reference import thin_coat as reference
from stats import chi2_test, unit


def test_registered_and_listed_with_six_presets():
    assert MODELS[model.ID] is model and model.LABEL == "Thin Coat"
    names = presets.names(model.ID)
    assert len(names) == 6 and {"amber_lacquer", "varnished_metal", "glazed_ceramic"} <= set(names)
    for name in names:
        assert presets.description(model.ID, name), name
        assert model.validate(presets.load(model.ID, name)).warnings == [], name


def test_the_reference_exposes_params_from_dict():
    """The documented API entry point: ``addon.reference.thin_coat.params_from_dict`` (docs/api.md)."""
    d = {"kappa_top": 200, "kappa_bottom": 1000, "eta": 1.5, "sigma_a": [0.1, 0.2, 0.3], "depth": 0.5,
         "bounces": 3, "base": {"type": "diffuse", "albedo": [0.5, 0.4, 0.3]}}
    p = reference.params_from_dict(d)
    assert p == model.params_from_dict(d) and p.bounces == 3 and p.base.albedo == (0.5, 0.4, 0.3)
    assert reference.eval(p, unit(0.3, 0.0, 0.9), unit(-0.3, 0.0, 0.9)).shape == (1, 3)


def test_round_trip_through_dict_and_json():
    for name in presets.names(model.ID):
        p = model.params_from_dict(presets.load(model.ID, name))
        assert model.params_from_dict(json.loads(json.dumps(p.to_dict()))) == p, name


def test_out_of_range_values_are_clamped_with_one_message_each():
    v = model.validate({"kappa_top": 1e7, "eta": 0.5, "sigma_a": [-1, 0, 2000], "depth": -1, "bounces": 7,
                        "base": {"type": "dielectric_rough", "ior": 5}})
    p = v.params
    assert (p.kappa_top, p.eta, p.sigma_a, p.depth, p.bounces, p.base.ior) == (
        model.MAX_KAPPA, 1.0001, (0.0, 0.0, 1000.0), 0.0, model.MAX_BOUNCES, 3.0)
    assert len(v.warnings) == 7
    for needle in ("kappa_top: 1e+07", "eta: 0.5", "sigma_a[0]: -1", "sigma_a[2]: 2000", "depth: -1", "bounces: 7",
                   "base: ior: 5"):
        assert any(needle in w and "clamped to" in w for w in v.warnings), needle
    nan = model.validate({"depth": float("nan")})
    assert nan.params.depth == 0.5 and "not finite" in nan.warnings[0]


@pytest.mark.parametrize("bad, message", [
    ({"bounces": 1.5}, "bounces: expected a whole number, got 1.5"),
    ({"bounces": "2"}, "bounces: expected a number"),
    ({"bounces": True}, "bounces: expected a number"),
    ({"kappa_top": 5, "roughness_top": 0.1}, "give either kappa_top or roughness_top"),
    ({"kappa_bottom": 5, "roughness_bottom": 0.1}, "give either kappa_bottom or roughness_bottom"),
    ({"base": {"type": "wood"}}, "type in dielectric_rough, conductor, diffuse, slab"),
    ({"base": "slab"}, "type in dielectric_rough, conductor, diffuse, slab"),
    ({"base": {"type": "slab", "ior": 1.5}}, "unknown parameter(s) ior"),
    ({"base": {"type": "diffuse", "ior": 1.5}}, "unknown parameter(s) ior"),
    ({"colour": [1, 0, 0]}, "unknown key(s) colour"),
    ({"sigma_a": [1, 2]}, "sigma_a: expected three numbers, got 2"),
    ({"eta": None}, "eta: expected a number"),
    ([1, 2], "expected a dict"),
])
def test_bad_input_is_refused_with_a_clear_message(bad, message):
    with pytest.raises(ParamError) as e:
        model.validate(bad)
    assert message in str(e.value) and "\n" not in str(e.value)


def test_whole_number_floats_are_accepted_as_bounces():
    assert model.params_from_dict({"bounces": 3.0}).bounces == 3
    assert isinstance(model.params_from_dict({"bounces": 3.0}).bounces, int)


@pytest.mark.parametrize("alpha, kappa", [(0.1, 200.0), (0.01, 2e4), (1.0, 2.0), (math.sqrt(2e-3), 1e3)])
def test_roughness_and_kappa_are_two_names_for_one_lobe(alpha, kappa):
    p = model.params_from_dict({"roughness_top": alpha, "roughness_bottom": alpha})
    assert p.kappa_top == pytest.approx(kappa, rel=1e-12) and p.kappa_bottom == pytest.approx(kappa, rel=1e-12)
    assert p.roughness_top == pytest.approx(alpha, rel=1e-12)
    again = model.params_from_dict(p.to_dict())  # the dict stores kappas only
    assert "roughness_top" not in p.to_dict() and again == p


def test_roughness_extremes_clamp_kappa_into_its_range():
    mirror = model.validate({"roughness_top": 0.0})
    assert mirror.params.kappa_top == model.MAX_KAPPA and mirror.warnings == []
    huge = model.validate({"roughness_bottom": 100.0})
    assert huge.params.kappa_bottom == pytest.approx(model.MIN_KAPPA)
    assert len(huge.warnings) == 1 and "roughness_bottom: 100" in huge.warnings[0]
    negative = model.validate({"roughness_top": -0.5})
    assert negative.params.kappa_top == model.MAX_KAPPA and "clamped to 0" in negative.warnings[0]


def test_every_base_round_trips_with_its_own_parameters():
    for base in model.BASE_TYPES:
        p = model.params_from_dict({"base": {"type": base}})
        assert set(p.to_dict()["base"]) == {"type"} | {prm.name for prm in model.BASE[base]}
        assert p.transmits == (base == "slab")


# ----------------------------------------------------------------------------- as a micrograin bulk

def test_a_thin_coat_is_a_micrograin_bulk():
    assert model.ID in micrograin.bulk_types()
    p = micrograin.params_from_dict({"bulk": {"type": model.ID, "preset": "varnished_metal"}})
    assert p.bulk.params == model.params_from_dict(presets.load(model.ID, "varnished_metal"))
    v = micrograin.validate({"bulk": {"type": model.ID, "bounces": 9}})
    assert v.params.bulk.params.bounces == model.MAX_BOUNCES and v.warnings[0].startswith("bulk: thin_coat: bounces")
    with pytest.raises(ParamError, match="bounces: expected a whole number"):
        micrograin.validate({"bulk": {"type": model.ID, "bounces": 1.5}})


def test_the_thin_coat_reference_says_it_samples_from_the_view():
    assert mg.samples_from_view(reference)
    assert not mg.samples_from_view(mg) and not mg.samples_from_view(scenes)


N = 200_000
COAT = {"kappa_top": 30, "kappa_bottom": 20, "eta": 1.4, "sigma_a": [0.2, 0.4, 0.8], "depth": 0.5, "bounces": 2}
BULKS = {
    "rough dielectric, light above": ({"type": "dielectric_rough", "ior": 2.25}, unit(0.5, 0.3, 0.6)),
    "diffuse, light above": ({"type": "diffuse", "albedo": [0.7, 0.6, 0.5]}, unit(0.5, 0.3, 0.6)),
    "slab, light below": ({"type": "slab"}, unit(-0.4, 0.5, -0.7)),
}


def _porous(base):
    return mg.params_from_dict({"filling_factor": 0.4, "anfractuosity": 0.5, "grain": {"type": "diffuse"},
                                "bulk": {"type": model.ID, **COAT, "base": base}})


def _sampled(p, wi, seed):
    return mg.sample(p, np.repeat(wi, N, 0), np.random.default_rng(seed).random((N, 3)))


@pytest.mark.parametrize("case", BULKS)
def test_porous_layer_over_a_thin_coat_samples_what_its_pdf_says(case):
    """As tests/unit/test_micrograin_sampling.py: chi-square of the layer's samples against its pdf (integrating
    to 1), and the mean weight against the albedo by deterministic quadrature of ``eval``."""
    base, wi = BULKS[case]
    p = _porous(base)
    s = _sampled(p, wi, zlib.crc32(case.encode()))
    assert np.all(np.isfinite(s.weight)) and np.all(s.weight >= 0) and (s.pdf > 0).mean() > 0.99
    result = chi2_test(s.wo, lambda wo: mg.pdf(p, np.repeat(wi, len(wo), 0), wo), res=10)
    assert result.p_value > 0.01, result
    assert result.integral == pytest.approx(1.0, abs=5e-3)
    albedo = scenes.directional_albedo(lambda a, b: mg.eval(p, b, a), wi[None], quadrature=(128, 256))[0]
    mean, err = s.weight.mean(axis=0), s.weight.std(axis=0) / np.sqrt(N)
    assert np.all(np.abs(mean - albedo) <= 4 * err + 0.01 * albedo), (mean, albedo, err)


def test_chi2_catches_the_thin_coat_pdf_taken_with_the_other_models_argument_order(monkeypatch):
    """Without the exchange (the density of the held direction given the drawn one) the test fails."""
    base, wi = BULKS["rough dielectric, light above"]
    p = _porous(base)
    s = _sampled(p, wi, 5)
    monkeypatch.setattr(mg, "_bulk_pdf", lambda bulk, a, b: reference.pdf(bulk.params, a, b))
    assert chi2_test(s.wo, lambda wo: mg.pdf(p, np.repeat(wi, len(wo), 0), wo), res=10).p_value < 1e-6
