"""SpongeCake multiple scattering's energy fraction network (issue 15, part 1): numpy inference against torch, the
quick train → export → load pipeline, the augmentation's symmetry, the side a view picks, the white limit, and the
shipped weights against their recorded held-out error."""
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from addon.bake import layer_rows, mlp, validation  # noqa: E402
from addon.bake import spongecake as ms  # noqa: E402
from addon.models import spongecake as model  # noqa: E402
from addon.reference import spongecake as ref  # noqa: E402
from training import dataset, energy_train, train  # noqa: E402


def _rows(n_layers, n=32, seed=3):
    return dataset.sample_layers(np.random.default_rng(seed), n, n_layers)


def _upper(n, seed=5):
    return dataset.stratified_hemisphere(np.random.default_rng(seed), n)


@pytest.mark.parametrize("n_layers, view", [(1, True), (2, True), (2, False), (3, True), (4, False)])
def test_numpy_fraction_matches_torch_through_the_shipped_float32_format(n_layers, view, tmp_path):
    """Either input format, told apart by the network's input count."""
    torch.manual_seed(n_layers)
    net = energy_train.make_network(ms.energy_input_count(n_layers, view))
    with torch.no_grad():
        net[-1].weight.normal_(0.0, 5.0)  # far from make_network's constant start, so the test can fail
    path = tmp_path / "energy.npz"
    exported = energy_train.to_mlp(net, {"layers": n_layers})
    mlp.save(path, exported.weights, exported.biases, exported.manifest)
    rows, w = _rows(n_layers, 36), _upper(36)
    x = ms.energy_inputs(rows, w, view)
    with torch.no_grad():
        expected = torch.sigmoid(net(torch.as_tensor(x.reshape(-1, x.shape[-1]), dtype=torch.float32)))
    q = ms.fraction_rows(rows, w, mlp.load(path))
    np.testing.assert_allclose(q, expected.numpy().reshape(-1, 3), rtol=1e-4, atol=1e-6)
    assert q.std() > 0.01


def test_the_augmentation_turns_the_inputs_of_a_stack_into_those_of_the_turned_stack():
    """Rotating and mirroring orientations and the direction about the normal is an exact symmetry of SpongeCake;
    ``rotated`` must give the inputs of the turned stack seen along the turned direction."""
    n_layers, rows, w = 2, _rows(2, 64), _upper(64)
    x = ms.energy_inputs(rows, w)[:, 0]
    generator = torch.Generator().manual_seed(3)
    turned = energy_train.rotated(torch.as_tensor(x), n_layers, generator).numpy()
    angle = torch.rand(64, generator=torch.Generator().manual_seed(3)).numpy() * 2.0 * np.pi
    assert not np.allclose(turned, x)
    at_w = slice(n_layers * ms.ENERGY_FEATURES, n_layers * ms.ENERGY_FEATURES + 3)
    c, s = np.cos(angle), np.sin(angle)
    for k in range(64):  # the sample's turn is its angle's, mirrored or not: check the whole input under each
        for sign in (1.0, -1.0):
            turn = np.array([[c[k], -s[k], 0], [s[k], c[k], 0], [0, 0, 1]]) @ np.diag([1.0, sign, 1.0])
            if np.allclose(turn @ w[k], turned[k, at_w], atol=1e-6):
                stack = rows[k:k + 1].copy()
                stack[0, :, layer_rows.ORIENTATION] = stack[0, :, layer_rows.ORIENTATION] @ turn.T
                expected = ms.energy_inputs(stack, (turn @ w[k])[None])[0, 0]
                np.testing.assert_allclose(turned[k], expected, atol=1e-5)
                break
        else:
            pytest.fail(f"sample {k}: the direction was not turned by a rotation (and mirror) about the normal")


def test_the_view_features_follow_a_smooth_tilted_flake_layer():
    """For surface flakes tilted 60° about x, the mirror image of the view about the flake normal o = (0, −sin 60°,
    cos 60°): along o it comes back along o (c² = 1, the projected area 1, up), and grazing from −y it goes down
    into the stack; fibers give the area of their own distribution and no mirror, hg layers area 1 and nothing."""
    o = np.array([0.0, -np.sin(np.pi / 3), 0.5])
    rows = np.zeros((2, 3, layer_rows.ROW))
    rows[:, :, layer_rows.TYPE] = [0, 1, 2]
    rows[:, :, layer_rows.ROUGHNESS] = 0.1
    rows[:, :, layer_rows.ORIENTATION] = o
    w = np.stack([o, [0.0, 0.995, np.sqrt(1.0 - 0.995 ** 2)]])
    f = ms.view_features(rows, w).reshape(2, 3, ms.ENERGY_VIEW_FEATURES)
    np.testing.assert_allclose(f[0, 0], [1.0, 1.0, o[2]], atol=1e-12)
    np.testing.assert_allclose(f[0, 1], [1.0, 0.1, 0.0], atol=1e-12)
    np.testing.assert_allclose(f[:, 2], [[0.0, 1.0, 0.0]] * 2, atol=1e-12)
    c = w[1] @ o
    assert f[1, 0, 2] == pytest.approx(2.0 * c * o[2] - w[1, 2]) and f[1, 0, 2] < -0.4


def test_a_view_from_below_takes_the_flipped_stack_seen_from_above():
    p = ref.params_from_dict({"layers": [
        {"type": "surface", "roughness": 0.2, "albedo": [0.9, 0.5, 0.2], "thickness": 0.5,
         "orientation": [0.6, 0.0, 0.8]},
        {"type": "fiber", "roughness": 0.4, "albedo": [0.7, 0.7, 0.7], "thickness": 2.0}]})
    w = _upper(16)
    below = w * np.array([1.0, 1.0, -1.0])
    flipped = layer_rows.flipped(layer_rows.stack_rows(p))
    np.testing.assert_allclose(ms.energy_fraction(p, below), ms.fraction_rows(np.repeat(flipped[None], 16, 0), w))
    assert not np.allclose(ms.energy_fraction(p, below), ms.energy_fraction(p, w))
    q = ms.energy_fraction(p, np.concatenate([w, below]))
    assert np.all((q > 0) & (q < 1))


def test_a_white_stack_gets_all_that_single_scattering_leaves_and_a_dark_one_the_networks_share():
    mu = np.asarray(model.energy_cosines())
    wo = ref.spherical(mu, np.zeros_like(mu))
    left = np.full((len(mu), 3), 0.4)
    lobes = np.full((len(mu), 3), 0.1)
    white = ref.params_from_dict({"layers": [{"albedo": [1.0, 1.0, 1.0], "thickness": 3.0}]})
    np.testing.assert_allclose(ms.fraction_limit(white, wo, mu, left, lobes), 4.0)
    dark = ref.params_from_dict({"layers": [{"albedo": [0.5, 0.5, 0.5], "thickness": 3.0}]})
    q = ms.energy_fraction(dark, wo)
    np.testing.assert_allclose(ms.fraction_limit(dark, wo, mu, left, lobes)[:-1], 4.0 * q[:-1], rtol=1e-12)
    assert np.all(q < 0.5)
    np.testing.assert_allclose(ms.fraction_limit(dark, wo, mu, left, np.zeros_like(lobes)), ms.MAX_SCALE)


def test_the_network_starts_at_the_constant_share_that_minimises_its_loss():
    """``best_constant_share`` is the weighted median of E_ms / left: no other constant q has a lower training loss
    Σ |q left − E_ms| / norm, here not the data's mean share, whose start stalled the 3- and 4-layer networks; the
    network's output is that constant for any input."""
    rng = np.random.default_rng(5)
    left = rng.uniform(0.05, 1.0, 400)
    energy = left * np.where(rng.random(400) < 0.7, rng.uniform(0.0, 0.1, 400), rng.uniform(0.5, 1.0, 400))
    norm = rng.uniform(0.01, 1.0, 400)
    samples = {"left": left, "energy": energy}
    best = energy_train.best_constant_share(samples, norm)

    def loss(q):
        return np.sum(np.abs(q * left - energy) / norm)

    mean_share = energy.sum() / left.sum()
    assert all(loss(best) <= loss(q) + 1e-12 for q in np.linspace(0.01, 0.99, 981))
    assert loss(mean_share) > 1.2 * loss(best)
    net = energy_train.make_network(7, best)
    with torch.no_grad():
        q = torch.sigmoid(net(torch.as_tensor(rng.normal(size=(16, 7)), dtype=torch.float32)))
    np.testing.assert_allclose(q.numpy(), best, rtol=1e-5)


def test_quick_energy_data_train_export_load(tmp_path, monkeypatch):
    data_dir, weights, held_out = tmp_path / "data", tmp_path / "weights", tmp_path / "held_out.npz"
    assert energy_train.main(["--quick", "--validation-set", str(held_out), "--workers", "1"]) == 0
    args = ["--quick", "--data", str(data_dir), "--out", str(weights), "--validation", str(held_out), "--workers", "1",
            "--threads", "1"]
    assert energy_train.main(args) == 0
    chunks = sorted(data_dir.rglob("chunk*.npz"))
    assert len(chunks) == 2 * ms.ENERGY_NETWORK_LAYERS  # every layer count by default
    stamps = [c.stat().st_mtime_ns for c in chunks]
    assert energy_train.main(args + ["--layers", "1"]) == 0
    assert [c.stat().st_mtime_ns for c in chunks] == stamps  # resumes: nothing made again
    data = energy_train.load(data_dir, 1)
    total = data["unscattered"] + data["single"] + data["multiple"]  # every path leaves once, with weight <= 1
    assert np.all(total <= 1.0 + 1e-9) and np.all(data["multiple"] >= 0) and data["multiple"].max() > 0
    monkeypatch.setattr(ms, "WEIGHTS", weights)
    mlp.load.cache_clear()
    for n_layers in range(1, ms.ENERGY_NETWORK_LAYERS + 1):
        m = ms.energy_network(n_layers).manifest
        assert m["layers"] == n_layers and m["training_configs"] > 0 and "held_out_validation" in m
    other, mean = tmp_path / "seed1", tmp_path / "mean"  # another seed's run, and the mean of the two
    assert energy_train.main(["--quick", "--data", str(data_dir), "--out", str(other), "--validation", str(held_out),
                              "--workers", "1", "--threads", "1", "--layers", "1", "--seed", "1"]) == 0
    assert energy_train.main(["--ensemble", str(weights), str(other), "--layers", "1", "--out", str(mean),
                              "--validation", str(held_out)]) == 0
    name = ms.energy_weights_path(1).name
    members, averaged = [mlp.load(f / name) for f in (weights, other)], mlp.load(mean / name)
    x = np.random.default_rng(0).normal(size=(16, members[0].n_inputs))
    np.testing.assert_allclose(averaged(x), 0.5 * (members[0](x) + members[1](x)), rtol=1e-4, atol=1e-5)
    assert len(averaged.manifest["ensemble_of"]) == 2 and "held_out_validation" in averaged.manifest
    mlp.load.cache_clear()


def test_an_ensemble_is_one_network_whose_output_is_its_members_mean(tmp_path):
    """``train.averaged``: members of different widths side by side, through the shipped float32 format, give
    the mean of their raw outputs (and so a fraction between theirs)."""
    n_in = ms.energy_input_count(2, True)
    members = []
    for seed, width in ((1, 16), (2, 24)):
        rng = np.random.default_rng(seed)
        shapes = [(n_in, width), (width, width), (width, width), (width, 1)]
        members.append(mlp.MLP(tuple(rng.normal(0, 0.5, s) for s in shapes),
                               tuple(rng.normal(0, 0.5, s[1]) for s in shapes), {"activation": "silu"}))
    weights, biases = train.averaged(members)
    mlp.save(tmp_path / "mean.npz", weights, biases, {"activation": "silu"})
    mean = mlp.load(tmp_path / "mean.npz")
    x = np.random.default_rng(3).normal(size=(64, n_in))
    outputs = [m(x) for m in members]
    np.testing.assert_allclose(mean(x), 0.5 * (outputs[0] + outputs[1]), rtol=1e-4, atol=1e-5)
    assert np.abs(outputs[0] - outputs[1]).mean() > 0.1  # so the test can fail
    assert [w.shape[1] for w in mean.weights] == [40, 40, 40, 1]
    mlp.load.cache_clear()


@pytest.mark.parametrize("n_layers", [1, 2, 3, 4])
def test_shipped_energy_networks_meet_their_recorded_held_out_error(n_layers):
    net = ms.energy_network(n_layers)
    recorded = net.manifest["held_out_validation"]
    scores = validation.energy_errors(energy_train.VALIDATION_SET, n_layers)
    assert scores["configs"] == recorded["configs"]
    for key in ("mean_relative_energy_error", "worst_relative_energy_error"):
        assert scores[key] == pytest.approx(recorded[key], rel=1e-3), key
    members = net.manifest.get("ensemble_of", [net.manifest])
    for key in ("training_configs", "paths_per_wi", "dataset_seed", "date", "code_version"):
        assert key in net.manifest, key
    assert all("split_validation" in m and "steps" in m for m in members)
    assert ms.energy_weights_path(n_layers).stat().st_size < 400_000
    json.dumps(net.manifest)


def test_only_stacks_without_a_substrate_take_the_fraction(monkeypatch):
    """Stacks of every depth take the energy fraction; stacks over a substrate (no data) keep the lobes' own
    energy."""
    asked = []
    monkeypatch.setattr(ms, "energy_fraction",
                        lambda params, w, net=None: asked.append(params) or np.full((len(w), 3), 0.5))
    mu = np.asarray(model.energy_cosines())

    def constant(value):
        return lambda stack, wo: np.full((len(wo), 3), value)

    layer = {"albedo": [0.3, 0.3, 0.3], "thickness": 1.0}  # far from white: no white limit
    for layers, substrate, used in ((1, None, True), (2, None, True), (3, None, True), (4, None, True),
                                    (1, {"type": "diffuse"}, False)):
        p = ref.params_from_dict({"layers": [layer] * layers, **({"substrate": substrate} if substrate else {})})
        asked.clear()
        scale = ms.energy_grid(p, constant(0.4), constant(0.1), mu, np.zeros(1))
        assert bool(asked) == used, (layers, substrate)
        np.testing.assert_allclose(scale, 0.5 * 0.4 / 0.1 if used else 1.0)


def test_the_model_returns_the_fraction_of_what_single_scattering_leaves_and_without_it_the_lobes_energy(tmp_path):
    """``model_energy_errors`` scores the reference's energy scale at each wi: with the fraction it is the network's
    share of what single scattering leaves (``energy_errors`` per stack, up to the margin), without it the lobes'
    own energy, another figure."""
    held_out = tmp_path / "held_out.npz"
    assert energy_train.main(["--quick", "--validation-set", str(held_out), "--workers", "1", "--layers", "1"]) == 0
    network_only = validation.energy_errors(held_out, 1)["per_config"]
    with_fraction = validation.model_energy_errors(held_out, 1)["per_config"]
    without = validation.model_energy_errors(held_out, 1, fraction=False)["per_config"]
    kept = [k for k, e in enumerate(network_only) if e is not None]
    assert len(kept) >= 4
    np.testing.assert_allclose([with_fraction[k] for k in kept], [network_only[k] for k in kept], atol=0.02)
    assert max(abs(without[k] - with_fraction[k]) for k in kept) > 0.05


def test_per_view_errors_count_what_the_summed_error_lets_cancel():
    """A prediction 20% high at one view and 20% low at another of the same energy: the summed error is 0, the
    per-view error 20%; a stack with too little energy to score is left out of both."""
    samples = {"energy": np.array([1.0, 1.0, 0.5, 0.5, 1e-9, 1e-9]), "config": np.array([0, 0, 1, 1, 2, 2])}
    predicted = np.array([1.2, 0.8, 0.55, 0.55, 1.0, 1.0])
    np.testing.assert_allclose(validation.relative_energy_errors(predicted, samples), [0.0, 0.1, np.nan])
    np.testing.assert_allclose(validation.per_view_energy_errors(predicted, samples), [0.2, 0.1, np.nan])
