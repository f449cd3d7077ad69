"""The neural_medium networks end to end on a tiny dataset: the training script exports what the add-on's numpy
inference reads (numpy = torch to 1e-5), the encoding, the table reconstruction and its energy measure."""
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from addon.bake import mlp  # noqa: E402
from addon.reference import neural_medium as nm  # noqa: E402
from training import medium_dataset, medium_train  # noqa: E402


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    data, out = tmp_path_factory.mktemp("data"), tmp_path_factory.mktemp("weights")
    assert medium_dataset.main(["--out", str(data), "--albedos", "0.7", "0.95", "--gs", "0.0", "0.6", "--quick",
                                "--workers", "1"]) == 0
    # a fifth of --quick's 3 s per network (at least one epoch): what is checked is the export, not the fit
    assert medium_train.main(["--data", str(data), "--out", str(out), "--minutes", "0.01",
                              "--hold-out", "a0.9500_g+0.600"]) == 0
    return data, out


def test_numpy_inference_equals_torch(trained):
    data, out = trained
    for kind in nm.KINDS:
        net = nm.network(kind, out)
        m = medium_train.load_material(sorted(data.glob("*.npz"))[0], kind)
        x, _, _ = medium_train.samples(m)
        torch_net = medium_train.make_network(0)
        linears = [layer for layer in torch_net if isinstance(layer, torch.nn.Linear)]
        with torch.no_grad():
            for layer, w, b in zip(linears, net.weights, net.biases):
                layer.weight.copy_(torch.from_numpy(w.T.astype(np.float32)))
                layer.bias.copy_(torch.from_numpy(b.astype(np.float32)))
            expected = torch_net(torch.from_numpy(x)).numpy()[:, 0]
        np.testing.assert_allclose(net(x)[:, 0], expected, rtol=1e-5, atol=1e-5)


def test_the_loss_weights_share_each_material_between_power_and_cells(trained):
    """--power-share s: weights average 1 per material, (1 - s) of it uniform and s in proportion to the power a cell
    and direction emit (the energy ratio's and a render's weighting)."""
    data, _ = trained
    m = medium_train.load_material(sorted(data.glob("*.npz"))[0], "multiple")
    power = nm.cell_powers(m["table"], m["rho_edges"], m["z_edges"]).ravel()
    for share in (0.0, 0.5, 1.0):
        _, y, w = medium_train.samples(m, share)
        assert w.mean() == pytest.approx(1.0, rel=1e-5) and len(w) == len(y) == power.size
        np.testing.assert_allclose(w, (1.0 - share) + share * power / power.mean(), rtol=1e-5)


def test_the_weights_are_the_papers_size_and_say_how_they_were_made(trained):
    _, out = trained
    for kind in nm.KINDS:
        net = nm.network(kind, out)
        assert [w.shape for w in net.weights] == [(6, 50), (50, 50), (50, 1)]
        assert 4 * sum(w.size + b.size for w, b in zip(net.weights, net.biases)) <= 12 * 1024  # float32, 11.8 KB
        m = net.manifest
        assert m["activation"] == "tanh" and m["encoding"] == nm.ENCODING
        assert m["target"] == "log(1 + Phi / (phi_0 albedo^albedo_power))"
        assert m["phi_0"] == nm.PHI_0 and m["albedo_power"] == nm.ALBEDO_POWER[kind]
        assert m["data"]["materials"] == ["a0.7000_g+0.000", "a0.7000_g+0.600", "a0.9500_g+0.000"]
        assert set(m["energy_ratio"]["held_out"]["per_material"]) == {"a0.9500_g+0.600"}
        assert all(math.isfinite(v) for v in m["energy_ratio"]["training"]["per_material"].values())


@pytest.mark.parametrize("power", [0, 3])
def test_the_prediction_inverts_the_target_through_the_albedos_power(power):
    """A network that outputs the target of Phi for one albedo predicts Phi there; the albedo's power in the manifest
    scales the prediction as albedo^k (k = 0: the paper's target), so albedo 0 predicts nothing for k > 0."""
    phi, albedo = 3.0e-5, 0.3
    y = float(nm.target(phi, albedo=albedo, albedo_power=power))
    net = mlp.MLP((np.zeros((6, 1)),), (np.array([y]),), {"activation": "tanh", "phi_0": nm.PHI_0,
                                                          "albedo_power": power})
    # the network's output is float32 (``mlp``): Phi within about 1e-6 here
    assert nm.predict(net, 1.0, 0.0, 0.5, 0.5, albedo, 0.0)[0] == pytest.approx(phi, rel=1e-5)
    assert nm.predict(net, 1.0, 0.0, 0.5, 0.5, 2 * albedo, 0.0)[0] == pytest.approx(phi * 2 ** power, rel=1e-5)
    assert (nm.predict(net, 1.0, 0.0, 0.5, 0.5, 0.0, 0.0)[0] == 0.0) == (power > 0)


def test_tanh_networks_differ_from_silu_ones():
    """The activation comes from the manifest: the same weights under SiLU give another function."""
    rng = np.random.default_rng(0)
    weights, biases = (rng.normal(size=(6, 4)), rng.normal(size=(4, 1))), (rng.normal(size=4), rng.normal(size=1))
    x = rng.random((5, 6))
    tanh = mlp.MLP(weights, biases, {"activation": "tanh"})(x)
    silu = mlp.MLP(weights, biases, {})(x)
    np.testing.assert_allclose(tanh, np.tanh(x @ weights[0] + biases[0]) @ weights[1] + biases[1], rtol=1e-5)
    assert not np.allclose(tanh, silu)


def test_encoding_maps_the_training_range_into_the_unit_cube():
    x = nm.encode(np.array([0.0, 256.0]), np.array([-256.0, 256.0]), np.array([0.0, math.pi]),
                  np.array([0.0, math.pi]), np.array([0.0, 0.999]), np.array([-1.0, 1.0]))
    np.testing.assert_allclose(x, [[0, 0, 0, 0, 0, 0], [1, 1, 1, 1, 1, 1]], atol=1e-12)
    assert nm.encode(1.0, 0.0, 0.0, 0.0, 1.0, 0.0)[0, 4] == 1.0  # albedos above ALBEDO_MAX are taken at it
    z = nm.encode(0.0, np.array([-3.0, 0.0, 3.0]), 0.0, 0.0, 0.5, 0.0)[:, 1]
    assert z[1] == 0.5 and z[0] + z[2] == pytest.approx(1.0)


def test_cell_centres_lie_inside_their_cells():
    rho_edges, z_edges = np.array([0.0, 0.5, 2.0, 30.0]), np.array([-40.0, -1.0, 0.0, 3.0])
    rho_c, z_c = nm.cell_centres(rho_edges, z_edges)
    assert np.all((rho_edges[:-1] < rho_c) & (rho_c < rho_edges[1:]))
    assert np.all((z_edges[:-1] < z_c) & (z_c < z_edges[1:]))


def test_table_energy_integrates_volume_and_solid_angle():
    """A constant Phi = 1 over a cylinder of radius 2 and height 3 emits 4 pi x its volume."""
    phi = np.ones((2, 3, 6, 5))
    energy = nm.table_energy(phi, [0.0, 1.0, 2.0], [0.0, 1.0, 2.0, 3.0])
    assert energy == pytest.approx(4.0 * math.pi * math.pi * 4.0 * 3.0)
    assert nm.bin_solid_angles(18, 18).sum() == pytest.approx(4.0 * math.pi)


def test_unknown_network_and_missing_weights_are_clear(tmp_path):
    with pytest.raises(ValueError, match="unknown network"):
        nm.network("triple")
    with pytest.raises(FileNotFoundError, match="missing"):
        nm.network("double", tmp_path)


# ------------------------------------------------------------------------------------------ the shipped networks

def test_the_shipped_networks_are_the_papers_size_and_trained_on_the_whole_grid():
    """The multiple network (the bake's) saw the dataset's whole default grid; the double network, kept for
    comparison, the grid of its time (42 materials, before g = 0.3 and 0.7 were added)."""
    grid = {f"a{a:.4f}_g{g:+.3f}" for a in medium_dataset.ALBEDOS for g in medium_dataset.GS}
    total = 0
    for kind in nm.KINDS:
        net = nm.network(kind)
        total += sum(np.asarray(w, np.float32).nbytes + np.asarray(b, np.float32).nbytes
                     for w, b in zip(net.weights, net.biases))
        m = net.manifest
        materials = set(m["data"]["materials"])
        assert (materials == grid) if kind == "multiple" else (materials < grid and len(materials) == 42)
        assert m["activation"] == "tanh"
        assert {"rho_edges", "z_edges", "theta", "phi"} <= set(m["grid"])
        assert m["energy_ratio"]["off_grid"]["per_material"]  # evaluated off the grid too
    assert total <= 24 * 1024  # the paper's two networks: 11.8 KB each


@pytest.mark.parametrize("albedo, g", [(0.0, 0.0), (1.0, 0.0), (0.5, 0.99), (0.5, -0.99), (0.999, 0.95)])
def test_the_shipped_tables_are_finite_and_non_negative_at_the_extremes(albedo, g):
    from addon.bake import neural_medium as nb
    from addon.models import neural_medium as model

    p = model.params_from_dict({"sigma_s": [albedo] * 3, "sigma_a": [1.0 - albedo] * 3, "g": g, "scale": 1.0})
    tables = nb.channel_tables(p)
    for kind in nm.KINDS:
        v = tables[0][kind].values
        assert np.all(np.isfinite(v)) and v.min() >= 0.0
    assert np.isfinite(nm.extrapolation_distance(albedo, g))


def test_the_network_check_measures_power_and_its_misplacement(tmp_path, monkeypatch):
    """``training.medium_network_check``: a table equal to the Monte Carlo one is exact (0, 0); twice it has an energy
    ratio of +100 % and misplaces its whole power once; the shipped networks give finite, non-negative measures."""
    from training import medium_network_check as check

    assert medium_dataset.main(["--out", str(tmp_path), "--albedos", "0.9", "--gs", "0.5", "--quick",
                                "--workers", "1"]) == 0
    path = next(tmp_path.glob("a*.npz"))
    energy, misplaced = check.table_errors(path, "multiple")
    assert all(math.isfinite(v) for v in check.table_errors(path, "double", "quadrature"))
    assert math.isfinite(energy) and misplaced >= 0.0
    mc = nm.dataset_tables(path)["multiple"].values
    for factor, expected in ((1.0, 0.0), (2.0, 1.0)):
        monkeypatch.setattr(nm, "table", lambda *args, f=factor: f * mc)
        assert check.table_errors(path, "multiple") == pytest.approx((expected, expected), abs=1e-12)
