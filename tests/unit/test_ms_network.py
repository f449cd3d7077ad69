"""SpongeCake multiple scattering: numpy inference against the torch training code, the quick train → export →
load pipeline, the shipped weights against their recorded validation errors, and the prediction's symmetries."""
import json
import math
import shutil

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from addon.bake import layer_rows, mlp, validation  # noqa: E402
from addon.bake import spongecake as ms  # noqa: E402
from addon.reference import spongecake as ref  # noqa: E402
from training import dataset, train  # noqa: E402

VALIDATION = train.VALIDATION_SET


def _rows(n_layers, n=64, seed=3):
    return dataset.sample_layers(np.random.default_rng(seed), n, n_layers)


def _random_network(n_layers, seed=0, area=False):
    torch.manual_seed(seed)
    net = train.make_network(n_layers, area)
    with torch.no_grad():
        net[-1].weight.mul_(20.0)  # far from the near-constant initial output, so the test can fail
        net[-1].bias[train.outputs(n_layers):] = 0.5  # area exponents about 1
    return net


@pytest.mark.parametrize("n_layers", [1, 2])
def test_numpy_inference_matches_torch_through_the_shipped_float32_format(n_layers, tmp_path):
    net = _random_network(n_layers)
    rows = _rows(n_layers)
    exported = train.to_mlp(net, {})
    mlp.save(tmp_path / "w.npz", exported.weights, exported.biases, {"layers": n_layers})
    loaded = mlp.load(tmp_path / "w.npz")
    net32 = train.make_network(n_layers).float()  # torch's float32 inference, as the network was trained
    net32.load_state_dict({k: v.float() for k, v in net.state_dict().items()})
    with torch.no_grad():
        raw = net32(torch.as_tensor(ms.features(rows), dtype=torch.float32)).double()
        lobe_t, w_t = ms.decode(raw, torch.as_tensor(rows), train.TorchOps)
    lobe_n, w_n = ms.decode(loaded(ms.features(rows)), rows)
    np.testing.assert_allclose(lobe_n, lobe_t.numpy(), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(w_n, w_t.numpy(), rtol=1e-5, atol=1e-7)
    assert np.ptp(lobe_n[:, :, layer_rows.ROUGHNESS]) > 0.1  # the outputs really vary


@pytest.mark.parametrize("n_layers,area", [(1, False), (2, False), (1, True), (2, True)])
def test_numpy_lobe_matches_the_differentiable_training_lobe(n_layers, area, monkeypatch, tmp_path):
    """The loss's W1 f_ss(params') + W2 / pi + the forward lobe (torch) and the add-on's eval_multiple (numpy)
    before its energy scale are one function for the viewer above, light from either side (below the viewer sees
    the flipped stack's prediction); with the area exponents (``--area``) too."""
    net = _random_network(n_layers, seed=1, area=area)
    exported = train.to_mlp(net, {})
    mlp.save(tmp_path / ms.weights_path(n_layers).name, exported.weights, exported.biases, {})
    monkeypatch.setattr(ms, "WEIGHTS", tmp_path)
    ms.forget_networks()
    rng = np.random.default_rng(5)
    data = {"rows": _rows(n_layers, 6), "wi": np.stack([dataset.stratified_sphere(rng, 18) for _ in range(6)]),
            "wo": np.stack([dataset.stratified_hemisphere(rng, 16) for _ in range(6)])}  # viewer above (see eval_multiple)
    net32 = train.make_network(n_layers, area)
    net32.load_state_dict({k: v.float().double() for k, v in net.state_dict().items()})
    if area:
        assert 0.1 < ms.predict(layer_rows.params_from_rows(data["rows"][0])).forward_area[0] < 10.0
    with torch.no_grad():
        torch_lobe = train.predicted_lobe(net32, *train.tensors(data)).numpy()
    data["ms"] = np.zeros(torch_lobe.shape)
    np.testing.assert_allclose(validation.predicted_lobes(data, energy=False), torch_lobe, rtol=1e-5, atol=1e-12)
    ms.forget_networks()


@pytest.mark.parametrize("n_layers", [1, 2])
def test_the_generator_reproduces_the_shipped_validation_set(n_layers):
    """The held-out set in tests/data was written by an earlier walk (``make validation-set``): the current one
    (next-event estimates as blocks) gives its first configuration again, to its float32 storage."""
    with np.load(dataset.shard_path(VALIDATION, n_layers, 0)) as shard:
        stored = {k: shard[k] for k in ("rows", "wi", "wo", "ms", "ss")}
        meta = json.loads(str(shard["meta"]))
    size = dataset.Size(meta["configs"], meta["shard"], meta["n_wi"], meta["n_wo"], meta["paths"], meta["max_depth"])
    rows, wi, wo, seeds = dataset.shard_inputs(n_layers, 0, size, meta["seed"])
    np.testing.assert_allclose(rows, stored["rows"], rtol=1e-12, atol=1e-15)  # last-bit rounding differs by CPU
    ms_, _, ss = dataset.simulate(rows[0], wi[0], wo[0], size, int(seeds[0]))
    np.testing.assert_allclose(ms_, stored["ms"][0], rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(ss, stored["ss"][0], rtol=1e-5, atol=1e-7)
    assert stored["ms"][0].max() > 0


def test_quick_dataset_train_export_load(tmp_path, monkeypatch):
    data_dir, weights = tmp_path / "data", tmp_path / "weights"
    assert dataset.main(["--quick", "--out", str(data_dir), "--workers", "1"]) == 0
    shards = sorted(data_dir.rglob("*.npz"))
    assert dataset.main(["--quick", "--out", str(data_dir), "--workers", "1"]) == 0  # resumes: nothing redone
    assert [s.stat().st_mtime_ns for s in shards] == [s.stat().st_mtime_ns for s in sorted(data_dir.rglob("*.npz"))]
    runs = [json.loads(line) for line in (data_dir / "runs.jsonl").read_text().splitlines()]  # the run log
    assert [(r["made"], r["cached"], r["complete"]) for r in runs] == [(len(shards), 0, True), (0, len(shards), True)]
    assert runs[0]["megabytes"] == runs[1]["megabytes"] == round(sum(s.stat().st_size for s in shards) / 1e6, 1)
    assert all(json.loads(str(np.load(s)["meta"]))["seconds"] >= 0 for s in shards)
    assert train.main(["--quick", "--data", str(data_dir), "--out", str(weights), "--validation", str(data_dir),
                       "--threads", "1"]) == 0
    for n_layers in range(1, ms.ENERGY_NETWORK_LAYERS + 1):  # trained apart (test_ms_energy_network.py)
        shutil.copy(ms.energy_weights_path(n_layers), weights)
    monkeypatch.setattr(ms, "WEIGHTS", weights)
    ms.forget_networks()
    for n_layers in (1, 2):
        manifest = ms.network(n_layers).manifest
        assert manifest["layers"] == n_layers and manifest["training_configs"] > 0
        assert "held_out_validation" in manifest and manifest["code_version"]
        p = ref.params_from_dict({"layers": [{"albedo": [0.9, 0.9, 0.9]}] * n_layers, "multiple_scattering": True})
        wi, wo = dataset.stratified_sphere(np.random.default_rng(0), 32), dataset.stratified_sphere(
            np.random.default_rng(1), 32)
        f = ref.eval(p, wi, wo) - ref.eval(ref.params_from_dict({"layers": [{"albedo": [0.9] * 3}] * n_layers}), wi, wo)
        assert np.all(np.isfinite(f)) and np.all(f >= 0) and f.max() > 0
    again = tmp_path / "again"
    assert train.main(["--quick", "--data", str(data_dir), "--out", str(again), "--validation", str(data_dir),
                       "--threads", "1", "--layers", "1", "--init", str(weights)]) == 0
    first = mlp.load(weights / ms.weights_path(1).name).manifest
    assert mlp.load(again / ms.weights_path(1).name).manifest["warm_started_from"]["steps"] == first["steps"]
    narrow, onwards = tmp_path / "narrow", tmp_path / "onwards"  # another width; a warm start keeps its network's
    assert train.main(["--quick", "--data", str(data_dir), "--out", str(narrow), "--validation", str(data_dir),
                       "--threads", "1", "--layers", "1", "--hidden", "24", "24"]) == 0
    assert train.main(["--quick", "--data", str(data_dir), "--out", str(onwards), "--validation", str(data_dir),
                       "--threads", "1", "--layers", "1", "--init", str(narrow)]) == 0
    for folder in (narrow, onwards):
        net = mlp.load(folder / ms.weights_path(1).name)
        assert net.manifest["hidden"] == [24, 24] == [w.shape[1] for w in net.weights[:-1]]
    one = dataset.load(data_dir, 1)  # another --seed: another start and batches, the same split
    (net_a, info_a), (net_b, info_b) = (train.train(one, 1, 0.002, seed=s, log=lambda *a, **k: None) for s in (0, 1))
    assert np.array_equal(info_a["val_index"], info_b["val_index"]) and len(info_a["val_index"]) < len(one["rows"])
    assert not torch.equal(net_a[0].weight, net_b[0].weight)
    ensemble = tmp_path / "ensemble"  # the mean of two runs of one form, as one network, scored
    assert train.main(["--ensemble", str(weights), str(again), "--layers", "1", "--out", str(ensemble),
                       "--validation", str(data_dir)]) == 0
    members = [mlp.load(f / ms.weights_path(1).name) for f in (weights, again)]
    mean = mlp.load(ensemble / ms.weights_path(1).name)
    x = ms.features(dataset.load(data_dir, 1)["rows"])
    np.testing.assert_allclose(mean(x), 0.5 * (members[0](x) + members[1](x)), rtol=1e-4, atol=1e-5)
    assert np.abs(members[0](x) - members[1](x)).max() > 1e-3  # so the test can fail
    assert [m["steps"] for m in mean.manifest["ensemble_of"]] == [m.manifest["steps"] for m in members]
    assert "held_out_validation" in mean.manifest and mean.manifest["hidden"] == [2 * w for w in members[0].hidden]
    packed = tmp_path / "pack.npz"  # one compact file to train on another machine
    assert dataset.main(["--out", str(data_dir), "--pack", str(packed)]) == 0
    for n_layers in (1, 2):
        full, small = dataset.load(data_dir, n_layers), dataset.load(packed, n_layers)
        assert np.array_equal(small["rows"], full["rows"]) and np.allclose(small["wo"], full["wo"], atol=1e-7)
        assert small["noise"] == dataset.noise(full) and small["meta"] == full["meta"]
        scale = full["ms"].max(axis=(1, 2, 3), keepdims=True)
        assert np.all(np.abs(small["ms"] - full["ms"]) <= 2.0 ** -(dataset.PACK_MANTISSA_BITS + 1) * full["ms"]
                      + 1e-4 * scale)
    assert train.main(["--quick", "--data", str(packed), "--out", str(tmp_path / "from-pack"), "--validation",
                       str(data_dir), "--threads", "1", "--layers", "1"]) == 0
    area = tmp_path / "area"  # one more output per layer, scored as the add-on runs it
    assert train.main(["--quick", "--data", str(data_dir), "--out", str(area), "--validation", str(data_dir),
                       "--threads", "1", "--layers", "1", "--init", str(weights), "--area"]) == 0
    manifest = mlp.load(area / ms.weights_path(1).name).manifest
    assert manifest["area_exponents"] and manifest["outputs"] == train.outputs(1, area=True)
    assert len(manifest["held_out_per_config"]) == len(dataset.load(data_dir, 1)["rows"])
    assert manifest["held_out_scored_by"] == "add-on"
    with pytest.raises(ValueError, match="same outputs"):
        train.main(["--ensemble", str(weights), str(area), "--layers", "1", "--out", str(tmp_path / "mixed")])
    plain = mlp.load(weights / ms.weights_path(1).name).manifest
    assert not plain["area_exponents"] and plain["held_out_scored_by"] == "add-on"
    assert train.main(["--rescore", "--training-form", "--layers", "1", "--out", str(weights), "--validation",
                       str(data_dir)]) == 0  # the same measure for both, to compare them
    assert mlp.load(weights / ms.weights_path(1).name).manifest["held_out_scored_by"] == "training form"
    fast = tmp_path / "fast"  # float32, some wi per step, another loss: recorded in the manifest
    monkeypatch.setattr(train, "PRECISION", train.PRECISION)  # main sets it for the process
    assert train.main(["--quick", "--data", str(data_dir), "--out", str(fast), "--validation", str(data_dir),
                       "--threads", "1", "--layers", "2", "--float32", "--wi-per-step", "2",
                       "--energy-floor", "1e-4", "--scaled-loss", "--energy-weight", "0.5",
                       "--learning-rate", "3e-4"]) == 0
    manifest = mlp.load(fast / ms.weights_path(2).name).manifest
    assert ((manifest["precision"], manifest["wi_per_step"], manifest["energy_floor"], manifest["energy_weight"],
             manifest["scaled_loss"], manifest["learning_rate"]) == ("float32", 2, 1e-4, 0.5, True, 3e-4))
    assert np.isfinite(manifest["held_out_validation"]["mean_relative_lobe_error"])
    ms.forget_networks()


@pytest.mark.parametrize("n_layers", [1, 2])
def test_shipped_weights_meet_their_recorded_validation_error(n_layers):
    """The manifest records the network's own error (before the energy scale of ``eval_multiple``)."""
    net = ms.network(n_layers)
    recorded = net.manifest["held_out_validation"]
    data = validation.load_shards(VALIDATION, n_layers)
    scores = validation.lobe_errors(data, validation.predicted_lobes(data, energy=False))
    assert scores["configs"] == recorded["configs"]
    for key in ("mean_relative_lobe_error", "worst_relative_lobe_error", "mean_relative_energy_error"):
        assert scores[key] == pytest.approx(recorded[key], rel=1e-3), key
    assert net.n_inputs == n_layers * ms.FEATURES


def test_shipped_manifests_say_how_the_networks_were_made():
    for n_layers in (1, 2):
        m = ms.network(n_layers).manifest
        for key in ("training_configs", "pairs_per_config", "paths_per_wi", "dataset_seed", "date", "code_version",
                    "activation", "hidden", "split_validation", "held_out_validation"):
            assert key in m, key
        assert ms.weights_path(n_layers).stat().st_size < 400_000
        json.dumps(m)


@pytest.fixture
def four_energy_azimuths(monkeypatch):
    """The energy tables of an oriented stack at 4 view azimuths (0, 90, 180 and 270 degrees) instead of 32, with the
    same samples per view: the same Monte Carlo noise, an eighth of the work."""
    from addon.models import spongecake as model

    monkeypatch.setattr(model, "ENERGY_AZIMUTHS", 4)
    ref._energy_tables.cache_clear()
    yield
    ref._energy_tables.cache_clear()


def test_seen_from_below_it_is_the_flipped_stack_and_the_lobes_are_reciprocal(four_energy_azimuths):
    p = ref.params_from_dict({"layers": [
        {"type": "fiber", "roughness": 0.3, "thickness": 0.7, "albedo": [0.9, 0.8, 0.7], "orientation": [0.6, 0, 0.8]},
        {"type": "surface", "roughness": 0.5, "thickness": 2.0, "albedo": [0.95, 0.95, 0.95]}],
        "multiple_scattering": True})
    flipped = layer_rows.params_from_rows(layer_rows.flipped(layer_rows.stack_rows(p)))
    rng = np.random.default_rng(2)
    wo = dataset.stratified_hemisphere(rng, 16) * [1, 1, -1]
    wi = dataset.stratified_hemisphere(rng, 16) * rng.choice([-1.0, 1.0], (16, 1))
    mirror = np.array([1.0, 1.0, -1.0])
    # the network's lobes (before the energy scale, which follows the view alone, as a Cycles closure weight does)
    np.testing.assert_allclose(ref.eval_multiple(p, wi, wo, ms.predict(p)),
                               ref.eval_multiple(flipped, wi * mirror, wo * mirror, ms.predict(flipped)),
                               rtol=1e-12, atol=1e-15)
    a, b = dataset.stratified_hemisphere(rng, 16), dataset.stratified_hemisphere(rng, 16)
    np.testing.assert_allclose(ref.eval_multiple(p, a, b, ms.predict(p)), ref.eval_multiple(p, b, a, ms.predict(p)),
                               rtol=1e-9)  # reciprocal
    # the scale seen from below is the flipped stack's seen from above (two Monte Carlo estimates of the same albedos)
    np.testing.assert_allclose(ref.energy_tables(p)[1], ref.energy_tables(flipped)[0], rtol=0.02)


def test_a_substrate_closes_the_multiple_scattering_lobes():
    p = ref.params_from_dict({"layers": [{"albedo": [0.9, 0.9, 0.9]}], "substrate": {"type": "diffuse"},
                              "multiple_scattering": True})
    wi = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    wo = np.array([[0.6, 0.0, 0.8], [0.6, 0.0, -0.8], [0.6, 0.0, 0.8]])
    f = ref.eval_multiple(p, wi, wo)
    assert f[0].min() > 0 and np.all(f[1:] == 0)


def test_deeper_stacks_are_lumped_into_two_groups_split_where_the_thickness_is_most_even():
    rows = _rows(4, n=64, seed=8)
    lumped, groups = ms.lumped_rows(rows)
    thickness = rows[..., layer_rows.THICKNESS]
    assert (np.diff(groups, axis=1) >= 0).all() and (groups[:, 0] == 0).all() and (groups[:, -1] == 1).all()
    imbalance = np.abs(2.0 * np.cumsum(thickness, axis=1)[:, :-1] - thickness.sum(axis=1, keepdims=True))
    top = (groups == 0).sum(axis=1)  # layers in the top group
    chosen = imbalance[np.arange(64), top - 1]
    np.testing.assert_allclose(chosen, imbalance.min(axis=1))
    for g in (0, 1):
        member = groups == g
        t = np.where(member, thickness, 0.0)
        np.testing.assert_allclose(lumped[:, g, layer_rows.THICKNESS], t.sum(axis=1))
        albedo = np.einsum("nl,nlc->nc", t, rows[..., layer_rows.ALBEDO]) / t.sum(axis=1)[:, None]
        np.testing.assert_allclose(lumped[:, g, layer_rows.ALBEDO], albedo)
        thickest = np.argmax(np.where(member, thickness, -1.0), axis=1)
        assert (lumped[:, g, layer_rows.TYPE] == rows[np.arange(64), thickest, layer_rows.TYPE]).all()


def test_a_group_without_thickness_is_lumped_with_its_thickest_members_albedo():
    rows = _rows(4, n=1, seed=10)
    rows[0, :, layer_rows.THICKNESS] = (5.0, 0.0, 0.0, 0.0)
    lumped, groups = ms.lumped_rows(rows)
    assert list(groups[0]) == [0, 1, 1, 1] and lumped[0, 1, layer_rows.THICKNESS] == 0.0
    np.testing.assert_array_equal(lumped[0, 1, layer_rows.ALBEDO], rows[0, 1, layer_rows.ALBEDO])


def test_a_layer_split_in_two_halves_gets_the_two_layer_networks_lambert_weights():
    """Three layers whose lower two are one layer cut in halves lump back into the two-layer stack."""
    two = _rows(2, n=16, seed=9)
    two[:, 0, layer_rows.THICKNESS] = two[:, 1, layer_rows.THICKNESS]  # the split falls between them
    three = np.concatenate([two[:, :1], two[:, 1:], two[:, 1:]], axis=1)
    three[:, 1:, layer_rows.THICKNESS] *= 0.5
    weights = slice(None, ms.AREA.start)  # the area exponents: one per layer (``test_grouped_area_exponents``)
    np.testing.assert_allclose(ms.predict_rows(three)[1][:, weights], ms.predict_rows(two)[1][:, weights], rtol=1e-12)
    lumped, _ = ms.lumped_rows(three)
    np.testing.assert_allclose(lumped, two, rtol=1e-12)


def test_grouped_area_exponents_go_to_the_layer_each_lumped_layer_stands_for():
    """A group's area exponent scales by the projected area of its thickest layer, whose orientation and roughness
    the lumped layer has; the other layers of the group get exponent 0."""
    rows = _rows(4, n=8, seed=4)
    rows[:, :, layer_rows.THICKNESS] = [0.5, 2.0, 1.0, 1.5]  # groups {0, 1} and {2, 3}: thickest 1 and 3
    lumped, groups = ms.lumped_rows(rows)
    raw = np.zeros((8, ms.output_widths(2)[2]))
    raw[:, -2:] = [0.3, -0.7]
    exponents = ms.decode(ms.grouped_raw(raw, groups, rows), rows)[1][:, ms.AREA]
    expected = np.log1p(np.exp([0.0, 0.3, 0.0, -0.7])) * [0, 1, 0, 1]
    np.testing.assert_allclose(exponents, np.broadcast_to(expected, exponents.shape), rtol=1e-12)


@pytest.mark.parametrize("n_layers", [3, 4])
def test_grouped_prediction_of_held_out_deeper_stacks_is_far_closer_than_none(n_layers):
    """The held-out 3- and 4-layer stacks (tests/data, the walk's multiple scattering): the grouped prediction's
    errors (docs/training.md; before the energy scale, whose reference albedos take minutes here: make bench
    measures them with it) against no multiple scattering at all (lobe and energy error 1)."""
    data = validation.load_shards(VALIDATION, n_layers)
    scores = validation.lobe_errors(data, validation.predicted_lobes(data, energy=False))
    assert scores["configs"] >= 12
    assert scores["mean_relative_lobe_error"] < 0.8 and scores["mean_relative_energy_error"] < 0.4
    p = ref.params_from_dict({"layers": [{"albedo": [0.9] * 3, "thickness": 0.5}] * n_layers,
                              "multiple_scattering": True})
    wi, wo = dataset.stratified_sphere(np.random.default_rng(0), 32), dataset.stratified_sphere(
        np.random.default_rng(1), 32)
    f = ref.eval_multiple(p, wi, wo)
    assert np.all(np.isfinite(f)) and np.all(f >= 0) and f.max() > 0


def test_training_augmentations_are_exact_symmetries_of_the_model():
    """Permuting RGB channels and rotating/mirroring about the normal maps f_ss of one stack onto f_ss of the
    augmented stack at the augmented directions (so they are free extra data for the Monte Carlo lobes too)."""
    rng = np.random.default_rng(4)
    rows = _rows(2, 5)
    batch = {"rows": rows, "wi": np.stack([dataset.stratified_hemisphere(rng, 4) for _ in range(5)]),
             "wo": np.stack([dataset.stratified_sphere(rng, 8) for _ in range(5)])}

    def single(b):
        out = np.zeros((5, 4, 8, 3))
        for c in range(5):
            p = layer_rows.params_from_rows(b["rows"][c])
            out[c] = ref.eval(p, np.repeat(b["wi"][c], 8, 0), np.tile(b["wo"][c], (4, 1))).reshape(4, 8, 3)
        return out

    batch["ms"] = single(batch)
    augmented = train.augment(batch, np.random.default_rng(7))
    assert not np.allclose(augmented["wi"], batch["wi"])
    np.testing.assert_allclose(single(augmented), augmented["ms"], rtol=1e-9, atol=1e-12)


def test_training_in_float32_computes_the_float64_loss(monkeypatch):
    rng = np.random.default_rng(6)
    n = 8
    data = {"rows": _rows(2, n), "wi": np.stack([dataset.stratified_hemisphere(rng, 4) for _ in range(n)]),
            "wo": np.stack([dataset.stratified_sphere(rng, 18) for _ in range(n)]),
            "ms": rng.gamma(0.5, 0.01, (n, 4, 18, 3))}
    net = _random_network(2, area=True)
    losses = {}
    for precision in (torch.float64, torch.float32):
        monkeypatch.setattr(train, "PRECISION", precision)
        with torch.no_grad():
            loss = train.lobe_loss(net.to(precision), data, np.arange(n))
        assert loss.dtype == precision
        losses[precision] = loss.item()
    assert losses[torch.float32] == pytest.approx(losses[torch.float64], rel=1e-4)


def test_training_on_some_wi_per_step_estimates_the_whole_loss_without_bias():
    """Every wi's terms of the loss are means over its own pairs, so the loss over k of n wi, averaged over the
    subsets, is the loss over all n (``--wi-per-step``: more steps for the same time); the draw keeps each wi
    with its lobes."""
    rng = np.random.default_rng(5)
    n, n_wi, n_wo = 6, 4, 8
    batch = {"rows": _rows(2, n), "wi": np.stack([dataset.stratified_hemisphere(rng, n_wi) for _ in range(n)]),
             "wo": np.stack([dataset.stratified_sphere(rng, n_wo) for _ in range(n)]),
             "ms": rng.gamma(0.5, 0.01, (n, n_wi, n_wo, 3))}
    net = _random_network(2, area=True)
    norm = torch.as_tensor(rng.uniform(0.5, 2.0, n))
    subsets = [(a, b) for a in range(n_wi) for b in range(a + 1, n_wi)]
    with torch.no_grad():
        whole = train.batch_loss(net, batch, norm).item()
        parts = [train.batch_loss(net, {**batch, "wi": batch["wi"][:, list(s)], "ms": batch["ms"][:, list(s)]},
                                  norm).item() for s in subsets]
    assert np.std(parts) > 0.01 * whole
    assert np.mean(parts) == pytest.approx(whole, rel=1e-12)

    drawn = train.some_wi(batch, 3, np.random.default_rng(1))
    for c in range(n):
        picked = [int(np.flatnonzero(np.all(batch["wi"][c] == w, axis=1))[0]) for w in drawn["wi"][c]]
        assert len(set(picked)) == 3
        np.testing.assert_array_equal(drawn["ms"][c], batch["ms"][c, picked])


@pytest.mark.parametrize("n_layers", [1, 2])
def test_a_zero_network_output_keeps_the_layer_parameters(n_layers):
    """... and a network without the forward lobe's outputs predicts none (albedo 0)."""
    rows = _rows(n_layers, 16)
    raw = np.zeros((16, train.outputs(n_layers)))
    lobes, weights = ms.decode(raw, rows)
    for k in range(n_layers):
        kind = rows[:, k, layer_rows.TYPE]
        flake = kind < 2
        np.testing.assert_allclose(lobes[flake, k, layer_rows.ROUGHNESS],
                                   np.clip(rows[flake, k, layer_rows.ROUGHNESS], *ms.ALPHA_RANGE), rtol=1e-6)
        np.testing.assert_allclose(lobes[:, k, layer_rows.THICKNESS], rows[:, k, layer_rows.THICKNESS], rtol=1e-6)
        np.testing.assert_allclose(lobes[:, k, layer_rows.ALBEDO] / np.log(2.0),
                                   np.clip(rows[:, k, layer_rows.ALBEDO], 1e-4, 1 - 1e-4), rtol=1e-6)
    np.testing.assert_allclose(weights[:, ms.W2R], np.log(2.0))
    np.testing.assert_allclose(weights[:, ms.W2T], np.log(2.0))
    np.testing.assert_allclose(weights[:, ms.FORWARD_G], 0.0)
    np.testing.assert_allclose(weights[:, ms.FORWARD_ALBEDO], np.log(2.0))
    np.testing.assert_allclose(weights[:, ms.FORWARD_THICKNESS], 1.0)
    without = ms.decode(raw[:, :-ms.FORWARD_OUTPUTS], rows)[1]
    np.testing.assert_allclose(without[:, :ms.FORWARD_G], weights[:, :ms.FORWARD_G])
    np.testing.assert_allclose(without[:, ms.FORWARD_ALBEDO], 0.0)


@pytest.mark.parametrize("n_layers", [1, 2])
def test_a_warm_start_goes_on_from_the_exported_network(n_layers):
    """Training from ``--init`` starts where the exported network is; one exported before the forward lobe gets its
    outputs added (faint), every other output unchanged."""
    rows = _rows(n_layers, 16)
    x = ms.features(rows)
    exported = train.to_mlp(_random_network(n_layers, seed=5), {})
    if n_layers == 2:  # as exported before the forward lobe
        exported = mlp.MLP(exported.weights[:-1] + (exported.weights[-1][:, :-ms.FORWARD_OUTPUTS],),
                           exported.biases[:-1] + (exported.biases[-1][:-ms.FORWARD_OUTPUTS],), {})
    net = train.make_network(n_layers)
    train.warm_start(net, exported)
    with torch.no_grad():
        raw = net(torch.as_tensor(x)).numpy()
    np.testing.assert_allclose(raw[:, :exported.weights[-1].shape[1]], exported(x), rtol=1e-5, atol=1e-6)  # float32
    if n_layers == 2:
        assert (ms.decode(raw, rows)[1][:, ms.FORWARD_ALBEDO] < 0.02).all()
    with_area = train.make_network(n_layers, area=True)  # --area from weights without the exponents
    train.warm_start(with_area, exported)
    with torch.no_grad():
        raw_area = with_area(torch.as_tensor(x)).numpy()
    np.testing.assert_allclose(raw_area[:, :exported.weights[-1].shape[1]], exported(x), rtol=1e-5, atol=1e-6)
    exponents = np.log1p(np.exp(raw_area[:, train.outputs(n_layers):]))
    assert exponents.shape[1] == n_layers and exponents.max() < 1e-2  # areas to about the power 0: the lobe as it was
    with pytest.raises(ValueError, match="neither"):
        train.warm_start(train.make_network(n_layers), train.to_mlp(train.make_network(3 - n_layers), {}))


def test_the_lobe_bound_splits_each_error_by_direction_into_parts_that_add_up_to_it():
    """``lobe_bound.error_by_region``: every stored pair lies in one region, the regions' errors add up to the mean
    lobe error and their truths to the whole lobe, and an error made only around the light's direction of travel is
    counted there and nowhere else."""
    from training import lobe_bound

    data = {k: v[:4] for k, v in validation.load_shards(VALIDATION, 1).items() if k != "meta"}
    counted = sum(where.astype(int) for where in lobe_bound.regions(data).values())
    assert (counted == 1).all()
    predicted = validation.predicted_lobes(data, energy=False)
    parts = lobe_bound.error_by_region(data, predicted)
    scores = validation.lobe_errors(data, predicted)
    assert sum(p["error"] for p in parts.values()) == pytest.approx(scores["mean_relative_lobe_error"], rel=1e-9)
    assert sum(p["truth"] for p in parts.values()) == pytest.approx(1.0, rel=1e-9)

    truth = data["ms"] * np.abs(data["wo"][:, None, :, 2:])
    forward = lobe_bound.regions(data)["forward"]
    assert forward.any()
    parts = lobe_bound.error_by_region(data, np.where(forward[..., None], 2.0 * truth + 0.01, truth))
    assert parts["forward"]["error"] > 0.0
    assert all(p["error"] == 0.0 for name, p in parts.items() if name != "forward")


@pytest.mark.parametrize("n_layers", [1, 2])
def test_the_area_exponents_scale_the_forward_lobe_by_the_layers_projected_areas_to_their_powers(n_layers):
    """``train.predicted_lobe`` of a network with the area exponents (``--area``): exponents near 0 keep the
    forward lobe; exponent p on the last layer (a flake layer) scales it by (σ(wi) σ(wo))^p, σ the reference's
    projected area of that layer; everything else is the network's without them. The add-on decodes the exponents
    as training does."""
    data = {k: v for k, v in validation.load_shards(VALIDATION, n_layers).items() if k != "meta"}
    flake = next(c for c, rows in enumerate(data["rows"]) if rows[-1, layer_rows.TYPE] < 1.5)
    data = {k: v[flake:flake + 1] for k, v in data.items()}
    rows, wi, wo = train.tensors(data)
    plain = train.outputs(n_layers)
    raw = torch.zeros((1, train.outputs(n_layers, area=True)), dtype=torch.float64)
    raw[0, plain - ms.FORWARD_OUTPUTS:plain] = torch.tensor((0.7, 0.3, -1.0, 2.0, -0.4))
    raw[0, plain:] = -60.0

    def lobe(last_exponent_raw):
        raw[0, -1] = last_exponent_raw
        return train.predicted_lobe(lambda x: raw, rows, wi, wo)[0].numpy().reshape(-1, 3)

    without = train.predicted_lobe(lambda x: raw[:, :plain], rows, wi, wo)[0].numpy().reshape(-1, 3)
    np.testing.assert_allclose(lobe(-60.0), without, rtol=1e-12, atol=1e-15)
    last = layer_rows.params_from_rows(data["rows"][0]).layers[-1]
    big_wi = np.repeat(data["wi"][0], len(data["wo"][0]), axis=0).astype(float)
    big_wo = np.tile(data["wo"][0], (len(data["wi"][0]), 1)).astype(float)
    weights = ms.decode(raw[:, :plain].numpy(), data["rows"].astype(float))[1][0]
    forward = ref.eval(ms.forward_params(weights), big_wi, big_wo) * np.abs(big_wo[:, 2:])
    areas = (ref._sigma(last, big_wi) * ref._sigma(last, big_wo))[:, None]
    assert areas.max() > 4.0 * areas.min()  # a layer whose area changes with the direction
    np.testing.assert_allclose(lobe(math.log(math.expm1(1.5))) - without, (areas ** 1.5 - 1.0) * forward, rtol=1e-9,
                               atol=1e-12)
    exponents = ms.decode(raw.numpy(), data["rows"].astype(float))[1][0, ms.AREA]
    np.testing.assert_allclose(exponents[-1], 1.5, rtol=1e-12)
    params = layer_rows.params_from_rows(data["rows"][0].astype(float))
    np.testing.assert_allclose(ref.area_scale(params, exponents, big_wi, big_wo)[:, None], areas ** 1.5, rtol=1e-9)
    with pytest.raises(ValueError, match="wide"):
        ms.decode(np.pad(raw.numpy(), ((0, 0), (0, 1))), data["rows"].astype(float))  # one output too many


@pytest.mark.parametrize("form", ["lobe", "halves", "forward", "area"])
def test_the_lobe_bound_fits_each_held_out_configuration_closer_than_the_network(form):
    """``training.lobe_bound`` optimises the lobe form per configuration from the network's prediction: on a few
    held-out stacks it ends below the error it starts from (a bound that did not move would say nothing), the halves
    form describes the same single scattering as the layer it cuts, and the forward lobe is an HG layer's single
    scattering in the reference."""
    from training import lobe_bound

    data = {k: v[:3] for k, v in validation.load_shards(VALIDATION, 1).items() if k != "meta"}
    halves = lobe_bound.halved(data) if form == "halves" else data
    wi, wo = data["wi"][0].astype(float), data["wo"][0].astype(float)
    pairs = np.repeat(wi, len(wo), axis=0), np.tile(wo, (len(wi), 1))
    if form == "halves":
        one, two = (ref.eval(layer_rows.params_from_rows(rows[0]), *pairs) for rows in (data["rows"], halves["rows"]))
        np.testing.assert_allclose(two, one, rtol=1e-9, atol=1e-12)
    if form == "forward":  # the forward lobe is one hg layer's single scattering, as decoded
        raw = np.zeros((1, train.outputs(1)))
        raw[0, -ms.FORWARD_OUTPUTS:] = (0.7, 0.3, -1.0, 2.0, -0.4)
        lobe = train.predicted_lobe(lambda x: torch.as_tensor(raw), torch.as_tensor(data["rows"][:1]),
                                    *(torch.as_tensor(w[None]) for w in (wi, wo)))[0].numpy()
        lobe0 = train.predicted_lobe(lambda x: torch.as_tensor(raw[:, :-ms.FORWARD_OUTPUTS]),
                                     torch.as_tensor(data["rows"][:1]),
                                     *(torch.as_tensor(w[None]) for w in (wi, wo)))[0].numpy()
        weights = ms.decode(raw, data["rows"][:1].astype(float))[1][0]
        np.testing.assert_allclose(weights[ms.FORWARD_G], 0.98 * np.tanh(0.7))
        np.testing.assert_allclose(weights[ms.FORWARD_ALBEDO], np.log1p(np.exp([0.3, -1.0, 2.0])))
        expected = ref.eval(ms.forward_params(weights), *pairs) * np.abs(pairs[1][:, 2:])
        np.testing.assert_allclose((lobe - lobe0).reshape(-1, 3), expected, rtol=1e-9, atol=1e-12)
    fitted = lobe_bound.best_lobes(halves, steps=60, rate=0.02, forward=form == "forward", area=form == "area")
    start, bound = (validation.lobe_errors(data, lobe_bound.best_lobes(halves, steps=0, rate=0.02,
                                                                       forward=form in ("forward", "area"))),
                    validation.lobe_errors(data, fitted))
    assert bound["mean_relative_lobe_error"] < start["mean_relative_lobe_error"] - 0.02
    if form == "area":  # the exponents take part: the fit is not the forward lobe's alone
        alone = lobe_bound.best_lobes(halves, steps=60, rate=0.02, forward=True)
        assert np.abs(fitted - alone).max() > 1e-6 * np.abs(alone).max()


def test_the_cross_validated_bound_scores_each_wi_with_a_fit_that_never_saw_it():
    """``lobe_bound.best_lobes(folds=3)``: the lobes at one group's wi do not change when that group's Monte Carlo
    does (they come from the fit to the other groups), they do when another group's does, and every group spans
    the elevations of the stratified wi."""
    from training import lobe_bound

    data = {k: v[:2] for k, v in validation.load_shards(VALIDATION, 1).items() if k != "meta"}
    group = lobe_bound.fold_of(data["wi"].shape[1], 3)
    assert [set(np.flatnonzero(group == k) // 3) for k in range(3)] == [{0, 1, 2}] * 3  # one wi per elevation row
    base = lobe_bound.best_lobes(data, steps=30, rate=0.02, area=True, folds=3)
    changed = data["ms"].copy()
    changed[:, group == 0] *= 3.0
    moved = lobe_bound.best_lobes({**data, "ms": changed}, steps=30, rate=0.02, area=True, folds=3)
    np.testing.assert_array_equal(moved[:, group == 0], base[:, group == 0])
    assert np.abs(moved[:, group != 0] - base[:, group != 0]).max() > 1e-3 * np.abs(base).max()
    plain, linear = (lobe_bound.best_lobes(data, steps=0, rate=0.02, area=True, view_linear=v) for v in (False, True))
    np.testing.assert_allclose(linear, plain, rtol=1e-9, atol=1e-15)  # its slopes start at 0
    width = train.outputs(1, area=True)
    a_and_b = torch.cat([torch.zeros(2, width), torch.full((2, width), 0.3)], dim=1).double()
    rows, wi, wo = train.tensors(data)
    linear = lobe_bound.lobes_at(a_and_b, rows, wi, wo, view_linear=True)
    for k in (0, 4):  # the outputs at one wi are a + b (1 - cos θi)
        at_k = lobe_bound.lobes_at(torch.full((2, width), 0.3) * (1.0 - wi[:, k:k + 1, 2]), rows, wi[:, k:k + 1], wo)
        np.testing.assert_allclose(linear[:, k:k + 1], at_k, rtol=1e-6)


def test_the_bound_fitted_to_a_fresh_walk_never_sees_the_stored_pairs(tmp_path, monkeypatch):
    """``lobe_bound.fresh_data``: each configuration simulated anew at directions of its own (not the stored ones),
    cached and reused; ``best_lobes(fit_to=...)``: the lobes do not move when the stored Monte Carlo does, they do
    when the fresh one does, and ``scored`` keeps the configurations ``lobe_errors`` scores."""
    from training import lobe_bound

    data = lobe_bound.scored({k: v[:2] for k, v in validation.load_shards(VALIDATION, 2).items()})
    assert len(data["rows"]) == 2
    dark = {**data, "ms": data["ms"] * np.array([1.0, 0.0])[:, None, None, None]}  # no multiple scattering: unscored
    np.testing.assert_array_equal(lobe_bound.scored(dark)["rows"], data["rows"][:1])
    size = dataset.Size(configs=0, n_wi=4, n_wo=8, paths=200)
    fresh = lobe_bound.fresh_data(data, size, cache=tmp_path)
    assert fresh["ms"].shape == (2, 4, 8, 3) and np.array_equal(fresh["rows"], data["rows"])
    assert np.abs(fresh["wi"][:, :, None] - data["wi"][:, None, :4]).sum(-1).min() > 1e-6  # directions of its own
    assert fresh["ms"].max() > 0.0
    monkeypatch.setattr(dataset, "simulate", lambda *a: pytest.fail("the cached walk ran again"))
    np.testing.assert_array_equal(lobe_bound.fresh_data(data, size, cache=tmp_path)["ms"], fresh["ms"])
    base = lobe_bound.best_lobes(data, steps=30, rate=0.02, area=True, fit_to=fresh)
    moved = lobe_bound.best_lobes({**data, "ms": 3.0 * data["ms"]}, steps=30, rate=0.02, area=True, fit_to=fresh)
    np.testing.assert_array_equal(moved, base)
    refit = lobe_bound.best_lobes(data, steps=30, rate=0.02, area=True, fit_to={**fresh, "ms": 3.0 * fresh["ms"]})
    assert np.abs(refit - base).max() > 1e-3 * np.abs(base).max()
    other = {**data, "rows": data["rows"][::-1]}
    with pytest.raises(ValueError, match="another stack"):
        lobe_bound.fresh_data(other, size, cache=tmp_path)
    with pytest.raises(ValueError, match="not both"):
        lobe_bound.best_lobes(data, steps=1, rate=0.02, folds=3, fit_to=fresh)


def test_the_cycles_forms_area_scale_along_the_normal_is_the_references():
    """``normal_area_scale`` (vectorised over layer rows, what texture bakes use) is the reference's ``area_scale``
    at wi = wo = n, for flakes, fibers and hg layers at any orientation; ``cycles_weights`` applies it to the forward
    lobe's albedo alone."""
    rows = _rows(2, n=24, seed=11)
    exponents = np.random.default_rng(2).uniform(0.0, 2.0, (24, 2))
    n = np.array([[0.0, 0.0, 1.0]])
    expected = [ref.area_scale(layer_rows.params_from_rows(r), e, n, n)[0] for r, e in zip(rows, exponents)]
    scale = ms.normal_area_scale(rows, exponents)
    np.testing.assert_allclose(scale, expected, rtol=1e-10)
    assert np.ptp(scale) > 0.5  # the layers' areas along the normal differ
    weights = np.random.default_rng(3).uniform(0.1, 1.0, (24, ms.AREA.start + 2))
    weights[:, ms.AREA] = exponents
    seen = ms.cycles_weights(rows, weights)
    np.testing.assert_allclose(seen[:, ms.FORWARD_ALBEDO], weights[:, ms.FORWARD_ALBEDO] * scale[:, None], rtol=1e-12)
    others = np.ones(ms.AREA.start, bool)
    others[ms.FORWARD_ALBEDO] = False
    np.testing.assert_array_equal(seen[:, others], weights[:, :ms.AREA.start][:, others])


def test_the_scaled_loss_compares_the_lobes_shape_at_the_monte_carlo_energy():
    """``--scaled-loss``: each wi's predicted lobe is scaled to the Monte Carlo's energy there before the lobe term, as
    the energy fraction renders stacks without a substrate; a truth that is the prediction times a per-wi, per-channel
    constant then costs nothing but the energy term, which the unscaled loss does not forgive."""
    rng = np.random.default_rng(8)
    n, n_wi, n_wo = 4, 4, 18
    batch = {"rows": _rows(2, n), "wi": np.stack([dataset.stratified_hemisphere(rng, n_wi) for _ in range(n)]),
             "wo": np.stack([dataset.stratified_sphere(rng, n_wo) for _ in range(n)])}
    net = _random_network(2, area=True)
    with torch.no_grad():
        predicted = train.predicted_lobe(net, *(torch.as_tensor(batch[k]) for k in ("rows", "wi", "wo"))).numpy()
    factor = rng.uniform(0.3, 3.0, (n, n_wi, 1, 3))
    batch["ms"] = predicted * factor / np.abs(batch["wo"][:, None, :, 2:])
    norm = torch.ones(n, dtype=torch.float64)
    with torch.no_grad():
        shape_only = train.batch_loss(net, batch, norm, train.Loss(energy_weight=0.0, scaled=True)).item()
        unscaled = train.batch_loss(net, batch, norm, train.Loss(energy_weight=0.0)).item()
        with_energy = train.batch_loss(net, batch, norm, train.Loss(energy_weight=1.0, scaled=True)).item()
        scaled = train.scaled_to(torch.as_tensor(predicted), train.target(batch)).numpy()
    assert shape_only == pytest.approx(0.0, abs=1e-12 * unscaled)
    assert unscaled > 0.1 * np.mean(predicted)
    assert with_energy > 0.1 * np.mean(predicted)
    np.testing.assert_allclose(scaled.mean(axis=2), (predicted * factor).mean(axis=2), rtol=1e-10)


def test_scoring_a_network_again_asks_for_no_rebake(monkeypatch):
    """Bake and fit keys hold what the networks predict from (``ms_identity``): a new held-out score in a manifest
    (``train --rescore``) leaves them, a change of what the network was trained on does not."""
    before = ms.ms_identity(2)
    manifest = ms.network(2).manifest
    monkeypatch.setitem(manifest, "held_out_validation", {"configs": 1, "mean_relative_lobe_error": 0.5})
    monkeypatch.setitem(manifest, "held_out_per_config", [0.5])
    assert ms.ms_identity(2) == before
    monkeypatch.setitem(manifest, "steps", manifest["steps"] + 1)
    assert ms.ms_identity(2) != before
