"""training.distill: per-configuration fits stored resumably, and a network regressed on them."""
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from addon.bake import mlp, validation  # noqa: E402
from addon.bake import spongecake as ms  # noqa: E402
from training import distill, train  # noqa: E402

HELD_OUT = train.VALIDATION_SET


def test_fits_are_stored_chunk_by_chunk_resume_and_score_below_their_start(tmp_path, monkeypatch):
    monkeypatch.setattr(distill, "CHUNK", 3)
    data = validation.load_shards(HELD_OUT, 2)
    folder = tmp_path / "fits"
    for part in ((0, 2), (1, 2)):  # two processes' shares
        distill.fit(data, 2, 7, folder, part, steps=40, log=lambda *a, **k: None)
    chunks = sorted(folder.glob("*.npz"))
    assert len(chunks) == 3
    stamps = [c.stat().st_mtime_ns for c in chunks]
    distill.fit(data, 2, 7, folder, steps=40, log=lambda *a, **k: None)  # resumes: nothing redone
    assert stamps == [c.stat().st_mtime_ns for c in chunks]
    index, raw = distill.load_fits(folder, 2)
    assert np.array_equal(index, distill.fitted_configurations(len(data["rows"]), 7))
    assert not set(index) & set(train.split(len(data["rows"]))[0])  # none of the split's validation
    start = ms.network(2)(ms.features(data["rows"][index].astype(np.float64)))
    before, after = distill.scores(data, index, [start, raw])
    assert after["alone"] < before["alone"] - 0.01 and after["scaled"] < before["scaled"] - 0.01


@pytest.mark.parametrize("target", distill.TARGETS)
def test_the_regression_learns_fits_that_are_a_function_of_the_layers(target):
    """Fits that a network can represent (the shipped network's outputs with the first lobe layer's albedo
    raised): the regressed network comes closer to them by the measure it regresses, on the configurations held back from it."""
    data = validation.load_shards(HELD_OUT, 2)
    index = np.arange(40)
    raw = ms.network(2)(ms.features(data["rows"][index].astype(np.float64)))
    raw[:, 1:4] += 0.5  # the first lobe layer's albedo, in its logit
    net, info = distill.regress(data, index, raw, ms.network(2), 0.25, target, log=lambda *a, **k: None)
    held_back = index[index % 10 == 0]
    fitted = {k: data[k][held_back] for k in ("rows", "wi", "wo", "ms")}
    start = train.make_network(2, True, ms.network(2).hidden)
    train.warm_start(start, ms.network(2))
    goal = torch.as_tensor(raw[held_back], dtype=train.PRECISION)
    goal_lobes = distill.fit_lobes(fitted, goal, np.arange(len(held_back)))
    total = train.target(fitted).sum(dim=(1, 2, 3))
    x = torch.as_tensor(ms.features(fitted["rows"]), dtype=train.PRECISION)

    def distance(n):
        if target == "outputs":
            return float(((n(x) - goal) ** 2).mean())
        lobes = train.predicted_lobe(n, *train.tensors(fitted))
        return float(((lobes - goal_lobes).abs().sum(dim=(1, 2, 3)) / total).mean())

    with torch.no_grad():
        before, after = distance(start), distance(net)
    assert after < 0.8 * before and info["distilled_from"] == target and info["train_configs"] == 40


def test_the_distilled_network_is_exported_scored_and_says_what_it_learned(tmp_path, monkeypatch):
    monkeypatch.setattr(distill, "CHUNK", 24)
    monkeypatch.setattr(train, "PRECISION", train.PRECISION)  # main sets it for the process
    fits, weights = tmp_path / "fits", tmp_path / "weights"
    assert distill.main(["fit", "--layers", "2", "--data", str(HELD_OUT), "--count", "24", "--steps", "20",
                         "--out", str(fits)]) == 0
    assert distill.main(["train", "--layers", "2", "--data", str(HELD_OUT), "--fits", str(fits), "--minutes", "0.02",
                         "--target", "outputs", "--out", str(weights)]) == 0
    trained = mlp.load(weights / ms.weights_path(2).name)
    assert trained.manifest["training_configs"] == 24 and "held_out_validation" in trained.manifest
    assert trained.manifest["distilled_from"] == "outputs"
    assert trained.manifest["warm_started_from"]["steps"] == ms.network(2).manifest["steps"]
    assert distill.main(["train", "--layers", "2", "--data", str(HELD_OUT), "--out", str(weights)]) == 2


def test_the_score_of_the_fits_is_theirs_and_a_network_scores_its_own_outputs(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(distill, "CHUNK", 8)
    monkeypatch.setattr(train, "PRECISION", train.PRECISION)
    data = validation.load_shards(HELD_OUT, 2)
    fits = tmp_path / "fits"
    assert distill.main(["fit", "--layers", "2", "--data", str(HELD_OUT), "--count", "8", "--steps", "40",
                         "--out", str(fits)]) == 0
    capsys.readouterr()
    assert distill.main(["score", "--layers", "2", "--data", str(HELD_OUT), "--fits", str(fits),
                         str(ms.WEIGHTS)]) == 0
    fitted, shipped = (json.loads(line) for line in capsys.readouterr().out.splitlines())
    assert fitted["lobes"] == "fits" and shipped["lobes"] == str(ms.WEIGHTS)
    index, raw = distill.load_fits(fits, 2)
    start = ms.network(2)(ms.features(data["rows"][index].astype(np.float64)))
    [again] = distill.scores(data, index, [start])
    assert again == {k: v for k, v in shipped.items() if k != "lobes"}
    assert fitted["alone"] < shipped["alone"] - 0.01 and fitted["scaled"] < shipped["scaled"] - 0.01
