"""The demo's report: every model's demo presets rendered small and checked through the page a person reads."""
import os
from html.parser import HTMLParser

import pytest

bpy = pytest.importorskip("bpy")

from addon import demo_page, presets  # noqa: E402
from addon.bake.exr import read_png  # noqa: E402
from addon.models import MODELS  # noqa: E402
from addon.operators import demo  # noqa: E402
from addon.reference import metrics  # noqa: E402
from addon.reference import scenes as ref_scenes  # noqa: E402

pytestmark = [pytest.mark.blender, pytest.mark.version_independent(
    "the demo page renders every model through the compare pipeline that the other tests run under 4.2")]
SCENES = ["sphere", "backlit"]  # backlit: not applicable to the opaque presets


class Page(HTMLParser):
    """The page as a list of elements: (tag, attributes, text inside, classes and ids of the enclosing elements)."""

    def __init__(self, text):
        super().__init__()
        self.elements, self.stack = [], []
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        element = {"tag": tag, "attrs": attrs, "text": "",
                   "within": {v for e in self.stack for v in (e["attrs"].get("id"), e["attrs"].get("class")) if v}}
        self.elements.append(element)
        if tag not in ("img", "meta"):
            self.stack.append(element)

    def handle_endtag(self, tag):
        while self.stack and self.stack.pop()["tag"] != tag:
            pass

    def handle_data(self, data):
        for e in self.stack:
            e["text"] += data

    def find(self, tag, cls=None):
        return [e for e in self.elements if e["tag"] == tag and (cls is None or e["attrs"].get("class") == cls)]


def _data():
    return {kind: set(getattr(bpy.data, kind).keys()) for kind in ("materials", "node_groups", "scenes", "texts")}


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    before = _data()
    reports = demo.run(list(MODELS), ["nodes"], SCENES, 4, 16, 0, str(out))
    assert _data() == before  # every temporary material, node group, scene and text removed again
    with open(out / "index.html", encoding="utf-8") as f:
        return reports, Page(f.read()), out


def test_every_model_and_demo_preset_has_a_summary_row(built):
    reports, page, _ = built
    expected = [(m, name) for m in MODELS for name in presets.demo_names(m)]
    assert [(r["model"], r["label"]) for r in reports] == expected
    rows = [e for e in page.find("tr") if "summary" in e["within"] and "data-model" in e["attrs"]]
    assert [(r["attrs"]["data-model"], r["attrs"]["data-preset"]) for r in rows] == expected
    assert {e["attrs"].get("id") for e in page.find("h2")} >= set(MODELS)  # a section per model
    for row in rows:  # the sphere's render time against the Principled BSDF's: "0.0512 s (1.3×)"
        assert "×)" in row["text"] and "%" in row["text"]


def test_the_overview_is_at_the_top_and_shows_every_preset(built):
    reports, page, out = built
    first_img = page.find("img")[0]
    assert first_img["attrs"]["src"] == demo_page.OVERVIEW and first_img["attrs"]["id"] == "overview"
    picture = read_png(os.path.join(out, demo_page.OVERVIEW))
    rows = max(len(presets.demo_names(m)) for m in MODELS)
    assert picture.shape[0] == rows * 16 + (rows - 1) * 4  # one 16 px strip per preset, columns per model
    assert picture.shape[1] == len(MODELS) * (3 * 16 + 4) + (len(MODELS) - 1) * 12


def test_the_heat_legend_states_its_fixed_scale(built):
    _, page, _ = built
    legend = next(e for e in page.elements if e["attrs"].get("id") == "heat-legend")
    assert float(legend["attrs"]["data-scale"]) == metrics.HEAT_SCALE
    assert f"{metrics.HEAT_SCALE:.0%}" in legend["text"] and "reference mean" in legend["text"]


def test_every_scene_shown_has_its_note_and_inapplicable_ones_no_percentage(built):
    reports, page, _ = built
    notes = {dt["text"]: dd["text"] for dt, dd in zip(page.find("dt"), page.find("dd"))}
    shown = {td["text"] for td in page.find("td", "scene")}
    assert shown == set(SCENES)
    assert all(notes[s] == ref_scenes.NOTES[s] for s in shown)
    opaque = [r for r in reports if r["not_applicable"]]
    assert opaque and all(set(r["not_applicable"]) == {"backlit"} and list(r["forms"]["nodes"]) == ["sphere"]
                          for r in opaque)
    na_rows = page.find("tr", "na")
    assert len(na_rows) == len(opaque)
    for row in na_rows:
        assert "not applicable" in row["text"] and "%" not in row["text"]
    # the transmitting presets did render it, each with a measured error
    assert any("backlit" in r["forms"]["nodes"] for r in reports)


def test_large_errors_name_the_approximations_and_link_the_accuracy_document(built):
    reports, page, out = built
    large = [r for r in reports if any(e["rel_rmse"] > demo_page.LARGE_ERROR for e in r["forms"]["nodes"].values())]
    boxes = [e for e in page.find("div", "approx")]
    assert {b["attrs"]["id"] for b in boxes} == {f"{r['model']}-{r['label']}-approx" for r in large}
    accuracy = [a["attrs"]["href"] for a in page.find("a") if a["text"] == "docs/accuracy.md"]
    assert accuracy and all(os.path.normpath(os.path.join(out, h)) == str(demo.ACCURACY) for h in accuracy)
    for r in large:
        box = next(b for b in boxes if b["attrs"]["id"] == f"{r['model']}-{r['label']}-approx")
        assert all(name in box["text"] for name, _ in r["approximations"])


def test_every_picture_shown_exists(built):
    _, page, out = built
    pictures = [img["attrs"]["src"] for img in page.find("img")]
    assert len(pictures) == 1 + sum(len(e) for r in built[0] for e in r["forms"].values())
    assert all(os.path.isfile(os.path.join(out, src)) for src in pictures)
