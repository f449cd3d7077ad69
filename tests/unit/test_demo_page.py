"""The demo's report page and console lines from synthetic reports (bpy-free, fast)."""
import subprocess
import sys
from html.parser import HTMLParser

import pytest

from addon import demo_page, presets
from addon.models import MODELS
from addon.reference import metrics
from addon.reference import scenes as ref_scenes


class Page(HTMLParser):
    """Elements as (tag, attributes, text inside, ids of the enclosing elements) and the rows of each table."""

    def __init__(self, text):
        super().__init__()
        self.elements, self.stack, self.tables = [], [], []
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        element = {"tag": tag, "attrs": dict(attrs), "text": "", "within": [e["attrs"].get("id") for e in self.stack]}
        self.elements.append(element)
        if tag not in ("img", "meta", "br"):
            self.stack.append(element)
        if tag == "table":
            element["rows"] = []
            self.tables.append(element)
        if tag == "tr":
            table = next(e for e in reversed(self.stack) if e["tag"] == "table")
            table["rows"].append(element)
            element["cells"] = []
        if tag in ("td", "th"):
            next(e for e in reversed(self.stack) if e["tag"] == "tr")["cells"].append(element)

    def handle_endtag(self, tag):
        while self.stack:
            if self.stack.pop()["tag"] == tag:
                break

    def handle_data(self, data):
        for e in self.stack:
            e["text"] += data

    def rows(self, table_id):
        return next(t["rows"] for t in self.tables if t["attrs"].get("id") == table_id)

    def find(self, tag, **attrs):
        return [e for e in self.elements if e["tag"] == tag and all(e["attrs"].get(k) == v for k, v in attrs.items())]


def _entry(rel, mapping, seconds=0.21, cached=False, picture="osl/sphere_side_by_side.png", principled=None):
    e = {"rel_rmse": rel, "mapping_rel_rmse": mapping, "cycles_seconds": seconds, "reference_seconds": 0.0123,
         "reference_cached": cached, "files": {"side_by_side": picture}}
    if principled is not None:
        e["principled"] = {"rel_rmse": principled, "cycles_seconds": 0.1, "panels": ["a", "b", "c", "d", "e"],
                           "files": {"principled_picture": picture.replace("side_by_side", "principled")}}
    return e


def _report(model, label, forms, not_applicable=None, approximations=(), principled_seconds=0.14):
    return {"model": model, "label": label, "samples": 16, "resolution": 32, "seed": 0, "forms": forms,
            "dir": f"{model}/{label}", "description": f"the {label} preset", "seconds": 12.5,
            "not_applicable": not_applicable or {}, "approximations": [list(a) for a in approximations],
            "principled_seconds": principled_seconds}


REPORTS = [
    _report("spongecake", "plastic",
            {form: {"sphere": _entry(0.03, 0.002, cached=form == "osl"), "plane": _entry(0.05, 0.01)}
             for form in ("nodes", "osl")},
            not_applicable={"backlit": "no light passes through this material"},
            approximations=[("mirror-G", "Eq. 12's G at the mirror configuration")]),
    _report("spongecake", "leaf",
            {form: {"sphere": _entry(0.52, 0.5), "backlit": _entry(1.83, 1.8)} for form in ("nodes", "osl")},
            approximations=[("lambert-hg", "HG layers as Lambert lobes"), ("diffusivity-exit", "exit at 60°")]),
    _report("thin_coat", "glazed_ceramic",
            {form: {"sphere": _entry(0.07, 0.068, principled=0.4)} for form in ("nodes", "osl")}),
]


@pytest.fixture(scope="module")
def page():
    return Page(demo_page.index_html(REPORTS, "../docs/accuracy.md", "2026-01-02", overview_width=3 * 100))


def test_overview_comes_first_then_the_summary_with_a_row_per_preset(page):
    imgs = page.find("img")
    assert imgs[0]["attrs"]["src"] == demo_page.OVERVIEW
    order = [e["attrs"].get("id") for e in page.elements if e["attrs"].get("id") in ("overview", "summary")]
    assert order == ["overview", "summary"]
    rows = [r for r in page.rows("summary") if r["cells"][0]["tag"] == "td"]
    assert [(r["attrs"]["data-model"], r["attrs"]["data-preset"]) for r in rows] == [
        (r["model"], r["label"]) for r in REPORTS]
    plastic, leaf, glaze = ([c["text"] for c in r["cells"]] for r in rows)
    assert plastic[2:4] == ["5.0% (plane)", "5.0% (plane)"]  # worst scene of each form
    assert plastic[4] == "0.14 s" and plastic[5] == "0.21 s (1.5×)"  # the sphere against the Principled BSDF
    assert "183.0% (backlit)" in leaf[2]


def test_large_errors_link_to_the_approximations_in_use(page):
    links = [a["attrs"]["href"] for a in page.find("a") if "▲" in a["text"]]
    assert links and set(links) == {"#spongecake-leaf-approx"}
    box = page.find("div", id="spongecake-leaf-approx")[0]
    assert "lambert-hg: HG layers as Lambert lobes" in box["text"] and "diffusivity-exit" in box["text"]
    assert any(a["attrs"]["href"] == "../docs/accuracy.md" for a in page.find("a") if "spongecake-leaf-approx"
               in a["within"])
    assert not page.find("div", id="spongecake-plastic-approx")  # no error above LARGE_ERROR there


def test_heat_legend_states_the_fixed_scale(page):
    legend = page.find("div", id="heat-legend")[0]
    assert float(legend["attrs"]["data-scale"]) == metrics.HEAT_SCALE
    ramp = next(e for e in page.elements if e["attrs"].get("class") == "ramp")
    assert ramp["attrs"]["style"].count("rgb(") == len(metrics.HEAT_STOPS)
    assert legend["text"].startswith("0%") and f"{metrics.HEAT_SCALE:.0%}" in legend["text"]


def test_scenes_have_notes_and_inapplicable_ones_no_percentage(page):
    notes = {dt["text"]: dd["text"] for dt, dd in zip(page.find("dt"), page.find("dd"))}
    shown = {td["text"] for td in page.find("td", **{"class": "scene"})}
    assert shown == {"sphere", "plane", "backlit"}
    assert all(notes[s] == ref_scenes.NOTES[s] for s in shown)
    na = page.find("tr", **{"class": "na"})
    assert len(na) == 1 and "not applicable: no light passes" in na[0]["text"] and "%" not in na[0]["text"]
    assert "spongecake-plastic" in na[0]["within"]


def test_times_say_what_they_measure_and_pictures_share_one_panel_width(page):
    cells = [c["text"] for t in page.tables for r in t["rows"] for c in r["cells"]]
    assert "0.0123 s (computed)" in cells and "cached" in cells and "0.00" not in " ".join(cells)
    widths = {}
    for img in page.find("img")[1:]:
        panels = 5 if "principled" in img["attrs"]["src"] else 3
        widths.setdefault(int(img["attrs"]["style"].split(":")[1].rstrip("px")) / panels, []).append(img)
    assert list(widths) == [demo_page.PANEL_PX]
    assert any("principled" in img["attrs"]["src"] for img in page.find("img"))


def test_console_progress_and_summary():
    line = demo_page.progress_line(3, 9, {**REPORTS[2], "seconds": 11.24}, 41.0, 110.0)
    assert line == "lamina: [3/9] thin_coat glazed_ceramic 11.2 s (elapsed 0:41, about 1:50 left)"
    # the spongecake presets took 12.5 s each: another spongecake preset and an unstarted model's at that mean too
    assert demo_page.time_left(REPORTS, ["spongecake", "micrograin"]) == pytest.approx(25.0)
    summary = demo_page.summary_lines(REPORTS)
    assert len(summary) == 3 and "leaf: worst node group 183.0% (backlit)" in summary[1]


def test_the_page_writer_imports_without_blender():
    code = "import sys; sys.modules['bpy'] = None; import addon.demo_page"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_every_model_has_a_demo_selection_its_validation_accepts():
    for model_id, model in MODELS.items():
        chosen = presets.demo_names(model_id)
        assert chosen and set(chosen) <= set(presets.names(model_id)), model_id
        for name in chosen:
            assert model.validate(presets.load(model_id, name)).warnings == []


def test_every_scene_kind_has_a_note():
    assert set(ref_scenes.NOTES) == set(ref_scenes.KINDS) and all(ref_scenes.NOTES.values())
