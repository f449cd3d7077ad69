"""The multiple-scattering speed bench: the sampling-only cost is the render at twice the samples less the render at
the bench's samples (the set-up cancels), per form, beside the whole render (``bench.spongecake.ms_render_times``)."""
import json

import pytest

bpy = pytest.importorskip("bpy")

import addon  # noqa: E402
from addon.bench import spongecake as bench  # noqa: E402
from addon.nodes import material  # noqa: E402
from addon.operators import blend_io  # noqa: E402

SETUP = {"nodes": 0.5, "osl": 2.0}  # a fake render's fixed cost: OSL compiles its shader
PER_SAMPLE = {False: 0.01, True: 0.013}  # and its cost per sample, without and with multiple scattering


@pytest.fixture(autouse=True)
def registered():
    addon.register()
    yield
    addon.unregister()


def _fake_render(calls):
    def render(mat, spec, samples, seed, path):
        record = json.loads(mat["lamina"])
        form = material.form_of(mat)
        ms = bool(record["params"]["multiple_scattering"])
        calls.append((form, ms, samples))
        jitter = 0.1 * (len(calls) % 3)  # later rounds are slower or faster: the fastest counts
        return None, SETUP[form] + jitter + PER_SAMPLE[ms] * samples

    return render


def test_the_sampling_cost_cancels_the_set_up_and_the_whole_render_keeps_it(monkeypatch):
    calls = []
    monkeypatch.setattr("addon.operators.cycles_render.render_cycles", _fake_render(calls))
    before = blend_io.snapshot()
    (row,) = bench.ms_render_times(["fabric"], samples=100, resolution=8, repeats=3)
    assert len(calls) == 3 * 4 * 2 and {c[2] for c in calls} == {100, 200}
    assert {(c[0], c[1]) for c in calls} == {(f, m) for f in ("nodes", "osl") for m in (False, True)}
    for form in ("nodes", "osl"):
        assert row[form] == pytest.approx(SETUP[form] + 1.0)  # the fastest whole render at 100 samples
        assert row[form + "_sampling"] == pytest.approx(100 * PER_SAMPLE[False])
        assert row[form + "_ms_sampling"] == pytest.approx(100 * PER_SAMPLE[True])
        assert row[form + "_ms_sampling"] / row[form + "_sampling"] == pytest.approx(1.3)
        assert row[form + "_ms"] / row[form] < 1.3  # the set-up dilutes the whole render's ratio
        assert len(row[form + "_sampling_rounds"]) == 3
    assert blend_io.snapshot() == before  # the bench's materials are removed


def test_the_speed_page_shows_both_tables(monkeypatch):
    row = {"preset": "fabric", "nodes": 2.0, "nodes_ms": 3.0, "nodes_sampling": 1.0, "nodes_ms_sampling": 1.4,
           "nodes_rounds": [1.4, 1.6], "nodes_sampling_rounds": [1.3, 1.5], "osl": 4.0, "osl_ms": 5.0,
           "osl_sampling": 2.0, "osl_ms_sampling": 2.5, "osl_rounds": [1.2, 1.3], "osl_sampling_rounds": []}
    monkeypatch.setattr(bench, "ms_render_times", lambda *a: [row])
    monkeypatch.setattr(bench, "bake_throughput", lambda size: ("fake", 1.0))
    page = bench.ms_speed_markdown(bench.MsSizes(), 64, 192)
    assert "| fabric | 2.00 | 3.00 | 1.50 | 1.40–1.60 | 4.00 | 5.00 | 1.25 | 1.20–1.30 |" in page
    assert "| fabric | 1.00 | 1.40 | 1.40 | 1.30–1.50 | 2.00 | 2.50 | 1.25 | – |" in page
    assert "128 samples less the fastest at 64" in page
