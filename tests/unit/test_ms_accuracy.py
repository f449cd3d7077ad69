"""Multiple scattering against Monte Carlo: the measurements of docs/accuracy.md's "Multiple scattering" section
(``addon.bench``) and thresholds on them.

Thresholds live in ``THRESHOLDS`` below; a weights manifest may override any key with its own
``accuracy_thresholds`` dict (training records them next to its validation errors), so retrained networks
carry their bounds. The threshold tests measure the shipped networks: with placeholder weights (a manifest
with fewer than ``MIN_TRAINING_CONFIGS`` training configurations) they are skipped, while the tests of the
measuring code always run. No predicted number is hard-coded.
"""
import json

import numpy as np
import pytest

from addon.reference import spongecake_truth as ms_truth
from addon.bench import spongecake as bench
from addon.bake import layer_rows, validation
from addon.bake import spongecake as ms
from addon.models import spongecake as model
from addon.reference import metrics
from addon.reference import scenes as S
from addon.reference import spongecake as ref

MIN_TRAINING_CONFIGS = 100
THRESHOLDS = {
    # Regression bounds a little above what the shipped networks measure (docs/accuracy.md), not goals; where issue
    # 15's goal is met, the goal itself.
    # White furnace of non-absorbing stacks of 1-4 layers, SS + MS with the energy scale: mean and worst |1 - a| and
    # the largest a. Issue 15's goal (3% / 10% / 1.005): 0.5% / 5.0% / 1.0037 measured (the network alone, without
    # the scale: 12.2% / 117.4% / 2.17).
    "furnace_mean": bench.FURNACE_GOAL[0],
    "furnace_worst": bench.FURNACE_GOAL[1],
    "furnace_max": bench.FURNACE_GOAL[2],
    # held-out validation set (64 stacks of each since 2026-12-07), with the energy scale: mean relative lobe error per
    # layer count (no MS at all scores 1.0); measured 42.9% (1 layer, 53 stacks scored) and 33.9% (2 layers); issue
    # 15's goal is 25%
    "validation_mean_lobe_error_1": 0.45,
    "validation_mean_lobe_error_2": 0.36,
    # the same for the network's lobes alone, before the energy scale: measured 38.7% and 38.2% (the two-layer
    # network is trained for the shape the energy scale renders: docs/training.md, the scaled loss)
    "validation_mean_network_lobe_error_1": 0.41,
    "validation_mean_network_lobe_error_2": 0.40,
    # rendered: SS + MS (network) vs Monte Carlo at most this times SS only vs Monte Carlo (presets, lit scenes)
    "rendered_ratio": 1.0,
}


def _manifests():
    return [ms.network(n).manifest for n in (1, 2)]


def thresholds() -> dict:
    out = dict(THRESHOLDS)
    for m in _manifests():
        out.update(m.get("accuracy_thresholds", {}))
    return out


def _placeholder() -> bool:
    return any(m.get("training_configs", 0) < MIN_TRAINING_CONFIGS for m in _manifests())


trained = pytest.mark.skipif(_placeholder(), reason="placeholder weights: the thresholds apply to trained networks")


# ------------------------------------------------------------------------------------- the measuring code

def test_white_furnace_configs_are_seeded_and_non_absorbing():
    a, b = bench.white_furnace_configs(3, seed=4), bench.white_furnace_configs(3, seed=4)
    assert a == b and a != bench.white_furnace_configs(3, seed=5)
    assert [len(c["layers"]) for c in a] == [1, 1, 1, 2, 2, 2, 3, 3, 3, 4, 4, 4]
    for c in a:
        p = model.params_from_dict(c)
        assert p.substrate is None and not p.delta_transmission and not p.multiple_scattering
        assert all(layer.albedo == (1.0, 1.0, 1.0) and not layer.has_fresnel for layer in p.layers)


@pytest.mark.usefixtures("coarse_energy_tables")
def test_the_dense_furnace_sees_oriented_stacks_at_every_azimuth():
    sizes = bench.MsSizes(furnace_configs=1)
    oriented = [model.anisotropic(model.params_from_dict(c)) for c in bench.white_furnace_configs(1, sizes.seed)]
    views = sum(bench.DENSE_AZIMUTHS if o else 1 for o in oriented) * len(bench.DENSE_THETAS)
    assert any(oriented)
    for form in ("osl", "nodes"):
        a = bench.dense_cycles_furnace(sizes, form)
        assert a.shape == (views,)
        assert np.all(np.isfinite(a)) and a.min() > 0.5 and a.max() < 1.5  # coarse tables: a measuring-code test


@pytest.mark.usefixtures("coarse_energy_tables")
def test_white_furnace_truth_is_one_and_single_scattering_falls_short():
    sizes = bench.MsSizes(furnace_configs=2, furnace_samples=1024, furnace_paths=4000)
    rows = bench.white_furnace(sizes)
    oriented = [model.anisotropic(model.params_from_dict(c)) for c in bench.white_furnace_configs(2, sizes.seed)]
    assert len(rows) == sum(len(bench.furnace_views(o)) for o in oriented) > 8 * len(bench.FURNACE_THETAS)
    assert {r["phi"] for r in rows if r["oriented"] and r["theta"] > 0} == set(bench.FURNACE_AZIMUTHS)
    truth = np.array([r["truth"] for r in rows])
    single = np.array([r["ss"] for r in rows])
    assert np.all(truth <= 1.0 + 1e-9) and np.all(truth > 0.95)  # 64 orders: little is cut off
    assert np.all(single < truth + 0.03)  # single scattering alone loses energy
    s = bench.furnace_summary(rows)
    assert s["ss"]["mean_vs_1"] == pytest.approx(np.mean(np.abs(1 - single)))
    assert s["truth"]["worst_vs_1"] == pytest.approx(np.max(np.abs(1 - truth)))
    assert s["ss_ms"]["worst_vs_truth"] >= s["ss_ms"]["mean_vs_truth"] >= 0
    for form in ("cycles", "nodes"):
        cycles = np.array([r[form] for r in rows])
        assert np.all(np.isfinite(cycles)) and s[form]["max"] == pytest.approx(cycles.max())
    network = np.array([r["network"] for r in rows])  # SS + the network's lobes before the energy scale
    assert np.all(network >= single - 1e-12) and s["network"]["max"] == pytest.approx(network.max())


def test_lobe_data_scores_zero_for_the_truth_and_one_for_nothing():
    p = model.params_from_dict({"layers": [{"type": "hg", "roughness": 0.3, "albedo": [0.9] * 3}],
                                "multiple_scattering": True})
    data = bench.lobe_data(p, n_wi=4, n_wo=32, paths=800, seed=1)
    assert data["ms"].shape == (1, 4, 32, 3) and data["rows"].shape == (1, 1, layer_rows.ROW)
    cos_o = np.abs(data["wo"][:, None, :, 2:])
    assert validation.lobe_errors(data, predicted=data["ms"] * cos_o)["mean_relative_lobe_error"] == 0
    none = validation.lobe_errors(data, predicted=np.zeros_like(data["ms"]))
    assert none["mean_relative_lobe_error"] == pytest.approx(1.0)
    assert 0 < none["mean_monte_carlo_noise"] < 0.5


def test_the_held_out_means_standard_error_is_the_configurations_spread_over_root_count():
    """The held-out table's "± its standard error": configurations off by 10%, 30% and 60% everywhere score a mean
    of 1/3 and a standard error of their sample deviation over √3."""
    data = {k: v for k, v in validation.load_shards(bench.MS_DEFAULT.validation, 1).items() if k != "meta"}
    kept = np.flatnonzero(validation.scored_lobes(data)[2])[:3]
    data = {k: v[kept] for k, v in data.items()}
    truth = validation.scored_lobes(data)[0]
    off = np.array([0.1, 0.3, 0.6])
    scores = validation.lobe_errors(data, predicted=truth * (1 + off)[:, None, None, None])
    assert scores["mean_relative_lobe_error"] == pytest.approx(off.mean())
    assert scores["standard_error_of_mean"] == pytest.approx(off.std(ddof=1) / np.sqrt(3))


@pytest.mark.usefixtures("coarse_energy_tables")
def test_the_held_out_table_scores_each_layer_count_in_its_own_process_as_in_this_one(tmp_path):
    """``bench.validation_errors`` (worker processes, one per layer count) gives what ``lobe_errors`` gives here,
    for the layer counts the set has and no others."""
    data = validation.load_shards(bench.MS_DEFAULT.validation, 1)
    (tmp_path / "layers1").mkdir()
    np.savez(tmp_path / "layers1" / "shard0000.npz", meta=json.dumps(data["meta"][0]),
             **{k: data[k][:2] for k in validation.ARRAYS})
    scores = bench.validation_errors(str(tmp_path), light_paths=2000, workers=2)
    assert set(scores) == {(1, True), (1, False)}
    two = {k: data[k][:2] for k in validation.ARRAYS}
    for energy in (True, False):
        here = validation.lobe_errors(two, validation.predicted_lobes(two, energy=energy))
        assert scores[1, energy]["configs"] == 2
        assert scores[1, energy]["mean_relative_lobe_error"] == pytest.approx(here["mean_relative_lobe_error"])


def test_failure_cases_are_the_papers_low_roughness_fibers():
    for label, layers in bench.FAILURE_CASES:
        assert all(layer["type"] == "fiber" and layer["roughness"] <= 0.1 and layer["orientation"][2] == 0
                   for layer in layers), label


@pytest.mark.slow
def test_failure_case_errors_are_measured():
    rows = bench.failure_case_errors(bench.MsSizes(failure_paths=400, failure_wi=4, failure_wo=32))
    assert len(rows) == len(bench.FAILURE_CASES)
    assert all(np.isfinite(r["mean_relative_lobe_error"]) and r["mean_monte_carlo_noise"] > 0 for r in rows)


# ------------------------------------------------------------------------------- thresholds (trained weights)

# Minutes (24 stacks with their random walks): make bench measures the same, and tests/unit/test_ms_energy.py checks
# the energy scale's behaviour in CI time.
@pytest.mark.slow
@trained
def test_white_furnace_energy_of_ss_plus_ms():
    s = bench.furnace_summary(bench.white_furnace(bench.MS_DEFAULT))["ss_ms"]
    t = thresholds()
    assert s["mean_vs_1"] <= t["furnace_mean"] and s["worst_vs_1"] <= t["furnace_worst"], s
    assert s["max"] <= t["furnace_max"], s


def _validation_set(n_layers: int) -> dict:
    try:
        return validation.load_shards(bench.MS_DEFAULT.validation, n_layers)
    except FileNotFoundError:
        pytest.skip("validation set missing (make validation-set)")


# Minutes: the energy scale's reference albedos for every configuration, both sides (make bench measures the same).
@pytest.mark.slow
@trained
@pytest.mark.parametrize("n_layers", [1, 2])
def test_held_out_lobe_error(n_layers):
    err = validation.lobe_errors(_validation_set(n_layers))["mean_relative_lobe_error"]
    assert err <= thresholds()[f"validation_mean_lobe_error_{n_layers}"]


@trained
@pytest.mark.parametrize("n_layers", [1, 2])
def test_held_out_lobe_error_of_the_network_alone(n_layers):
    data = _validation_set(n_layers)
    err = validation.lobe_errors(data, validation.predicted_lobes(data, energy=False))["mean_relative_lobe_error"]
    assert err <= thresholds()[f"validation_mean_network_lobe_error_{n_layers}"]


@trained
@pytest.mark.slow
@pytest.mark.parametrize("name", bench.MS_DEFAULT.presets)
def test_rendered_ss_plus_ms_is_closer_to_monte_carlo_than_ss_alone(name):
    from addon import presets

    p = model.params_from_dict({**presets.load(model.ID, name), "multiple_scattering": True})
    p_ss = ms_truth.single_scattering(p)
    settings = ms_truth.TruthSettings(paths=4000, albedo_paths=4000, stride=3)
    for spec in (S.sphere_scene(resolution=32), S.plane_scene(resolution=(32, 16)), S.furnace_scene(resolution=(16, 8))):
        truth = ms_truth.multiple_scattering_truth(p, spec, settings)
        single = S.reference_image(spec, lambda wi, wo: ref.eval(p_ss, wi, wo),
                                   bsdf_albedo=lambda wo: ref.furnace_albedo(p_ss, wo, n=2048))
        network = S.reference_image(spec, lambda wi, wo: ref.eval(p, wi, wo),
                                    bsdf_albedo=lambda wo: ref.furnace_albedo(p, wo, n=2048))
        gt, s = single + truth["image"], truth["samples"]
        err_net, err_ss = metrics.rel_rmse(network, gt, s), metrics.rel_rmse(single, gt, s)
        assert err_net <= thresholds()["rendered_ratio"] * err_ss, (spec.name, err_net, err_ss)


PRESET_SPHERE_GOAL = 0.08  # issue 15: the network's lobes against Monte Carlo on the fabric and window_shade spheres


@trained
def test_the_page_measures_the_shipped_networks_and_the_preset_spheres_meet_the_goal():
    """docs/accuracy.md (``make bench``) was made with the shipped lobe networks (their training times, which the
    page quotes from the manifests), and on it the reference with the network's lobes is within issue 15's goal on
    the fabric and window_shade spheres."""
    from pathlib import Path

    page = (Path(__file__).resolve().parents[2] / "docs" / "accuracy.md").read_text(encoding="utf-8")
    section = page[page.index("### Rendered: SS + MS vs Monte Carlo on the presets"):]
    for m in _manifests():
        assert f"{m['training_seconds']} s)" in page, m["layers"]
    header = next(line for line in section.splitlines() if line.startswith("| preset | scene |"))
    column = [c.strip() for c in header.strip("|").split("|")].index("network")
    for name in ("fabric", "window_shade"):
        row = next(line for line in section.splitlines() if line.startswith(f"| {name} | sphere |"))
        assert float([c.strip() for c in row.strip("|").split("|")][column].rstrip("%")) / 100 <= PRESET_SPHERE_GOAL
