"""The speed benches that compare two materials (multiple scattering on against off, ``bench.spongecake.
ms_render_times``; the fitted mapping against the analytic one, ``bench.common.fitted_speed_section``): the
sampling-only cost is each round's render at ``SAMPLING_FACTOR`` times the samples less its render at the bench's
samples (the set-up and the round's drift cancel), the median over the rounds, per form, beside the whole render."""
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


RENDERS_PER_ROUND = 8  # two forms, with and without multiple scattering, at two sample counts


def _fake_render(calls, hiccup_round: int | None = None):
    def render(mat, spec, samples, seed, path):
        record = json.loads(mat["lamina"])
        form = material.form_of(mat)
        ms = bool(record["params"]["multiple_scattering"])
        calls.append((form, ms, samples))
        this_round = (len(calls) - 1) // RENDERS_PER_ROUND
        drift = 0.1 * (this_round % 3)  # later rounds are slower or faster: the fastest whole render counts
        hiccup = 5.0 if this_round == hiccup_round and not ms and samples > 100 else 0.0  # one slow render
        return None, SETUP[form] + drift + hiccup + PER_SAMPLE[ms] * samples

    return render


def test_the_sampling_cost_cancels_the_set_up_and_the_drift_and_the_whole_render_keeps_them(monkeypatch):
    calls = []
    monkeypatch.setattr("addon.operators.cycles_render.render_cycles", _fake_render(calls, hiccup_round=1))
    before = blend_io.snapshot()
    (row,) = bench.ms_render_times(["fabric"], samples=100, resolution=8, repeats=3)
    assert len(calls) == 3 * RENDERS_PER_ROUND and {c[2] for c in calls} == {100, 100 * bench.SAMPLING_FACTOR}
    assert {(c[0], c[1]) for c in calls} == {(f, m) for f in ("nodes", "osl") for m in (False, True)}
    between = 100 * (bench.SAMPLING_FACTOR - 1)
    for form in ("nodes", "osl"):
        c = row[form]
        assert c["base"] == pytest.approx(SETUP[form] + 1.0)  # the fastest whole render at 100 samples
        assert c["base_sampling"] == pytest.approx(between * PER_SAMPLE[False])  # the hiccup's round ignored
        assert c["sampling"] == pytest.approx(between * PER_SAMPLE[True])
        assert c["sampling_ratio"] == pytest.approx(1.3)
        assert c["ratio"] < 1.3  # the set-up dilutes the whole render's ratio
        assert len(c["sampling_rounds"]) == 3 and min(c["sampling_rounds"]) < 1.0  # the hiccup
    assert blend_io.snapshot() == before  # the bench's materials are removed


def test_the_speed_page_shows_both_tables(monkeypatch):
    row = {"preset": "fabric",
           "nodes": {"base": 2.0, "other": 3.0, "ratio": 1.5, "rounds": [1.4, 1.6], "base_sampling": 1.0,
                     "sampling": 1.4, "sampling_ratio": 1.45, "sampling_rounds": [1.3, 1.5]},
           "osl": {"base": 4.0, "other": 5.0, "ratio": 1.25, "rounds": [1.2, 1.3], "base_sampling": 2.0,
                   "sampling": 2.5, "sampling_ratio": float("nan"), "sampling_rounds": []}}
    row["per_point_nodes"] = (120, 150)
    monkeypatch.setattr(bench, "ms_render_times", lambda *a: [row])
    page = bench.ms_speed_markdown(bench.MsSizes(), 64, 192)
    assert "| fabric | 2.00 | 3.00 | 1.50 | 1.40–1.60 | 4.00 | 5.00 | 1.25 | 1.20–1.30 |" in page
    assert "| fabric | 120 | 150 | 1.25 |" in page
    assert "| fabric | 1.00 | 1.40 | 1.45 | 1.30–1.50 | 2.00 | 2.50 | – | – |" in page  # the rounds' median ratio
    assert f"render at {64 * bench.SAMPLING_FACTOR} samples less its render at 64" in page


def test_fastest_renders_render_in_rounds_so_a_drift_touches_every_material_alike(monkeypatch):
    """A machine that slows down while the bench runs must not make the material rendered last look slower."""
    from addon.bench import common

    calls = []

    def render(mat, spec, samples, seed, path):
        calls.append(mat.name)
        return None, 1.0 + 0.5 * len(calls)  # every render slower than the one before

    monkeypatch.setattr("addon.operators.cycles_render.render_cycles", render)
    mats = {}

    def materials_of(name):
        mats.update({label: bpy.data.materials.new(f"bench {label}") for label in ("a", "b")})
        return mats

    (row,) = common.fastest_renders(["x"], materials_of, samples=4, resolution=8, repeats=3)
    assert calls == ["bench a", "bench b"] * 3
    assert row["b"] - row["a"] == pytest.approx(0.5)  # the first round's renders, one after the other


def test_the_fitted_mapping_is_timed_against_the_analytic_one_by_sampling_alone(monkeypatch):
    """Issue 14's cost goal compares what shading costs: an OSL shader that compiles longer with its tables must not
    count, a fitted mapping that shades slower must."""
    from addon.bench import common

    calls = []
    setup = {"analytic": 1.0, "fitted": 3.0}  # the fitted shader compiles longer
    per_sample = {"analytic": 0.010, "fitted": 0.009}  # and shades faster

    def render(mat, spec, samples, seed, path):
        mapping = json.loads(mat["lamina"])["mapping"]
        calls.append((material.form_of(mat), mapping, samples))
        return None, setup[mapping] + per_sample[mapping] * samples

    monkeypatch.setattr("addon.operators.cycles_render.render_cycles", render)
    monkeypatch.setattr(common.presets, "names", lambda model_id: ["plastic"])
    before = blend_io.snapshot()
    lines = common.fitted_speed_section("spongecake", samples=100, resolution=8, repeats=2)
    assert len(calls) == 2 * 2 * 2 * 2  # rounds × forms × mappings × sample counts
    assert {c[:2] for c in calls} == {(f, m) for f in ("nodes", "osl") for m in ("analytic", "fitted")}
    row = next(line for line in lines if line.startswith("| plastic"))
    assert row == "| plastic | 3.00 | 2.70 | 0.90 | 0.90–0.90 | 3.00 | 2.70 | 0.90 | 0.90–0.90 |"
    assert blend_io.snapshot() == before


def test_per_point_nodes_counts_what_varies_over_the_surface_through_groups_and_not_what_cycles_folds():
    """A Math chain on the view (through a group's input and out of it) counts; the same chain on constants, a
    group input left unlinked and a node that reaches no output do not."""
    from addon.bench.common import per_point_nodes

    group = bpy.data.node_groups.new("lamina test per-point", "ShaderNodeTree")
    group.interface.new_socket("x", in_out="INPUT", socket_type="NodeSocketFloat")
    group.interface.new_socket("y", in_out="INPUT", socket_type="NodeSocketFloat")
    group.interface.new_socket("sum", in_out="OUTPUT", socket_type="NodeSocketFloat")
    group.interface.new_socket("twice y", in_out="OUTPUT", socket_type="NodeSocketFloat")
    g_in, g_out = group.nodes.new("NodeGroupInput"), group.nodes.new("NodeGroupOutput")
    add, twice = group.nodes.new("ShaderNodeMath"), group.nodes.new("ShaderNodeMath")
    add.operation, twice.operation = "ADD", "MULTIPLY"
    group.links.new(g_in.outputs["x"], add.inputs[0])
    group.links.new(g_in.outputs["y"], add.inputs[1])
    group.links.new(g_in.outputs["y"], twice.inputs[0])
    group.links.new(add.outputs[0], g_out.inputs["sum"])
    group.links.new(twice.outputs[0], g_out.inputs["twice y"])

    mat, tree, out = material.empty_material("lamina test per-point")
    nodes, links = tree.nodes, tree.links
    bsdf = nodes.new("ShaderNodeBsdfGlossy")
    geometry, value = nodes.new("ShaderNodeNewGeometry"), nodes.new("ShaderNodeValue")
    on_view, on_value, unused = (nodes.new("ShaderNodeVectorMath"), nodes.new("ShaderNodeMath"),
                                 nodes.new("ShaderNodeMath"))
    on_view.operation = "LENGTH"
    links.new(geometry.outputs["Incoming"], on_view.inputs[0])
    links.new(value.outputs[0], on_value.inputs[0])
    links.new(geometry.outputs["Incoming"], unused.inputs[0])
    varying_group, constant_group = nodes.new("ShaderNodeGroup"), nodes.new("ShaderNodeGroup")
    varying_group.node_tree = constant_group.node_tree = group
    links.new(on_view.outputs["Value"], varying_group.inputs["x"])  # its y unlinked: "twice y" stays constant
    links.new(on_value.outputs[0], constant_group.inputs["x"])
    after = nodes.new("ShaderNodeMath")
    links.new(varying_group.outputs["sum"], after.inputs[0])
    links.new(varying_group.outputs["twice y"], after.inputs[1])
    links.new(after.outputs[0], bsdf.inputs["Roughness"])
    links.new(constant_group.outputs["sum"], bsdf.inputs["Anisotropy"])
    links.new(bsdf.outputs[0], out.inputs["Surface"])
    try:
        assert per_point_nodes(mat) == 3  # on_view, the varying group's ADD, after
        links.new(on_view.outputs["Value"], varying_group.inputs["y"])
        assert per_point_nodes(mat) == 4  # and its MULTIPLY
    finally:
        bpy.data.materials.remove(mat)
        bpy.data.node_groups.remove(group)
