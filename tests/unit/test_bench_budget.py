"""Fit to budget's bench (``addon.bench.budget``): its measurements resume where an earlier run stopped, render the
errors only of the configurations the tables show and have not rendered yet, and its table counts what rendered
within the budget. Cycles is replaced by recorded stand-ins here; ``make bench`` renders."""
import json
from dataclasses import replace

import pytest

from addon import presets
from addon.bench import budget as bench
from addon.models import MODELS
from addon.nodes import budget


@pytest.fixture(scope="module")
def plastic():
    p = MODELS["spongecake"].params_from_dict(presets.load("spongecake", "plastic"))
    return p, budget.candidates("spongecake", p, ("nodes", "osl"), mappings=("analytic",))


@pytest.fixture
def stand_ins(monkeypatch, plastic):
    """Cycles' part of the bench recorded: the materials measured and the candidates whose errors were rendered."""
    _, cs = plastic
    calls = {"measured": [], "rendered": []}

    def measure(model_id, name, p, sizes, repeats):
        calls["measured"].append(name)
        return {"model": model_id, "candidates": [c.to_json() for c in cs],
                "seconds": [1.0 + c.seconds for c in cs], "principled": 1.0, "rendered": {}}

    def rendered_errors(model_id, p, cands, indices):
        calls["rendered"].append(sorted(indices))
        return {i: {"error": cands[i].error, "noise": 0.001} for i in indices}

    monkeypatch.setattr(bench, "measure", measure)
    monkeypatch.setattr(bench, "rendered_errors", rendered_errors)
    return calls


def test_measurements_resume_and_render_only_what_is_missing(plastic, stand_ins, tmp_path):
    p, cs = plastic
    path = str(tmp_path / "measurements.json")
    entries = [("spongecake", "plastic", p)]
    bench.measurements(entries, path, sizes=None, progress=lambda _: None)
    shown = sorted(bench.shown(cs))
    assert stand_ins == {"measured": ["plastic"], "rendered": [shown]}

    bench.measurements(entries, path, sizes=None, progress=lambda _: None)
    assert stand_ins == {"measured": ["plastic"], "rendered": [shown]}  # nothing again

    with open(path, encoding="utf-8") as f:
        data = json.load(f)
    del data["plastic"]["rendered"][str(shown[-1])]
    with open(path, "w", encoding="utf-8") as f:
        json.dump(data, f)
    bench.measurements(entries, path, sizes=None, progress=lambda _: None)
    assert stand_ins["measured"] == ["plastic"] and stand_ins["rendered"][-1] == [shown[-1]]


def test_an_interrupted_run_keeps_what_it_measured(plastic, stand_ins, tmp_path, monkeypatch):
    p, _ = plastic
    path = str(tmp_path / "measurements.json")

    def interrupted(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(bench, "rendered_errors", interrupted)
    with pytest.raises(KeyboardInterrupt):
        bench.measurements([("spongecake", "plastic", p), ("spongecake", "copy", p)], path, sizes=None,
                           progress=lambda _: None)
    with open(path, encoding="utf-8") as f:
        assert set(json.load(f)) == {"plastic", "copy"}  # both measured before any error was rendered


def test_the_choice_table_counts_the_renders_within_their_budget(plastic):
    _, cs = plastic
    accurate, cheap = replace(cs[0], error=0.05, seconds=10.0), replace(cs[1], error=0.055, seconds=5.0)
    cands, seconds = {"plastic": ("spongecake", cs[0].params, [accurate, cheap])}, {("plastic", 0): 10.0,
                                                                                ("plastic", 1): 5.0}

    def rendered(error):
        return {("plastic", 0): {"error": 0.05, "noise": 0.0}, ("plastic", 1): {"error": error, "noise": 0.0}}

    lines = bench.choice_table(cands, seconds, rendered(0.055))
    assert sum(line.startswith("| plastic |") for line in lines) == len(bench.BUDGETS) == 4
    assert lines[-1].endswith(": 4 of 4.")
    assert bench.choice_table(cands, seconds, rendered(0.08))[-1].endswith(": 2 of 4.")  # within 5% and 10% only
