"""training.compare: networks scored on the same configurations, paired, and split by multiple scattering."""
import dataclasses
import json

import numpy as np
import pytest

from addon.bake import mlp, validation
from addon.bake import spongecake as ms
from training import compare, train

HELD_OUT = train.VALIDATION_SET


@pytest.fixture(scope="module")
def two_layer():
    return validation.load_shards(HELD_OUT, 2)


def nudged(net: mlp.MLP, amount: float) -> mlp.MLP:
    """``net`` with its last layer's biases moved by ``amount``: another network, close to it."""
    return dataclasses.replace(net, biases=net.biases[:-1] + (net.biases[-1] + np.float32(amount),))


def test_a_network_against_itself_differs_by_exactly_nothing(two_layer):
    shipped = ms.network(2)
    first, again = compare.compare(two_layer, [shipped, shipped])
    assert again["minus_first"] == {"mean": 0.0, "standard_error": 0.0}
    assert first["mean_relative_lobe_error"] == again["mean_relative_lobe_error"] > 0


def test_the_paired_difference_is_the_difference_of_the_means_known_closer_than_either(two_layer):
    first, other = compare.compare(two_layer, [ms.network(2), nudged(ms.network(2), 0.05)])
    assert other["minus_first"]["mean"] == pytest.approx(
        other["mean_relative_lobe_error"] - first["mean_relative_lobe_error"], abs=1e-12)
    assert other["minus_first"]["mean"] != 0.0
    assert 0.0 < other["minus_first"]["standard_error"] < min(first["standard_error_of_mean"],
                                                              other["standard_error_of_mean"])


def test_the_quarters_go_from_least_to_most_multiple_scattering_and_average_to_the_mean(two_layer):
    truth, _, keep = validation.scored_lobes(two_layer)
    amount = np.where(keep, truth.mean(axis=(1, 2, 3)), np.nan)
    quarters = compare.by_multiple_scattering(two_layer, amount)
    assert len(quarters) == compare.QUARTERS and quarters == sorted(quarters) and quarters[0] < quarters[-1]
    sizes = [len(g) for g in np.array_split(np.arange(keep.sum()), compare.QUARTERS)]
    assert np.average(quarters, weights=sizes) == pytest.approx(np.nanmean(amount))


def test_the_split_is_what_training_holds_out_and_says_who_saw_it(two_layer):
    val, trained_on = train.split(len(two_layer["rows"]))
    held = compare.split_configurations(two_layer)
    assert len(held["rows"]) == len(val) and not set(val) & set(trained_on)
    assert np.array_equal(held["ms"], two_layer["ms"][np.sort(val)])
    seen = compare.split_configurations(two_layer, trained_on=True)
    assert len(seen["rows"]) == len(val)
    assert np.array_equal(seen["ms"], two_layer["ms"][np.sort(trained_on)[:len(val)]])
    net = ms.network(2)
    for configs, unseen in ((len(trained_on), True), (len(trained_on) + 1, False), (None, False)):
        manifest = {k: v for k, v in net.manifest.items() if k != "training_configs"}
        if configs is not None:
            manifest["training_configs"] = configs
        assert compare.split_unseen(dataclasses.replace(net, manifest=manifest), len(two_layer["rows"])) is unseen


def test_the_command_prints_one_line_per_network_and_refuses_a_missing_one(tmp_path, capsys):
    shipped = ms.weights_path(1).parent
    assert compare.main(["--layers", "1", "--data", str(HELD_OUT), str(shipped), str(shipped)]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [line["set"] for line in lines] == ["split", "split"] and lines[1]["minus_first"]["mean"] == 0.0
    assert lines[0]["split_unseen"] is False  # the shipped network did not train on this set's other 90%
    assert compare.main(["--layers", "1", "--data", str(HELD_OUT), "--trained-on", str(shipped)]) == 0
    assert json.loads(capsys.readouterr().out)["set"] == "trained on"
    assert compare.main(["--layers", "1", "--held-out", str(tmp_path)]) == 2
    assert "no 1-layer network in" in capsys.readouterr().err


def test_the_noise_by_quarter_is_the_monte_carlo_noise_the_score_reports(two_layer):
    record, = compare.compare(two_layer, [ms.network(2)])
    _, _, keep = validation.scored_lobes(two_layer)
    sizes = [len(g) for g in np.array_split(np.arange(keep.sum()), compare.QUARTERS)]
    noise = record["noise_by_multiple_scattering"]
    assert np.average(noise, weights=sizes) == pytest.approx(record["mean_monte_carlo_noise"])
    assert noise[0] > noise[-1]  # the least multiple scattering is the noisiest, relative to itself


def test_with_the_energy_scale_a_network_scores_as_if_shipped_and_the_shipped_folder_stays():
    data = {k: v[:2] for k, v in validation.load_shards(HELD_OUT, 1).items() if k != "meta"}
    shipped_folder, shipped = ms.WEIGHTS, ms.network(1)
    np.testing.assert_array_equal(compare.predicted_lobes(data, shipped, energy_scale=True),
                                  validation.predicted_lobes(data))
    other = nudged(shipped, 0.05)
    scaled = compare.predicted_lobes(data, other, energy_scale=True)
    assert ms.WEIGHTS == shipped_folder and np.array_equal(ms.network(1).biases[-1], shipped.biases[-1])
    assert not np.allclose(scaled, validation.predicted_lobes(data))
    assert not np.allclose(scaled, compare.predicted_lobes(data, other, energy_scale=False))  # the scale acts
