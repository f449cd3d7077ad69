"""The demo's report page (``index.html``) and console summary, written from the demo's report dicts (bpy-free).

``operators.demo.run`` renders and measures; this module only turns its reports into text, so it is tested without
Blender. A report is ``compare_run.compare_params``'s dict plus what the demo adds:

* ``dir``: the preset's folder relative to the page (its pictures' paths are relative to it);
* ``description``: the preset's description;
* ``not_applicable``: {scene: why it was not rendered} (an opaque material's backlit scene);
* ``approximations``: [[name, what it does], ...], the mapping's approximations in use for the preset;
* ``principled_seconds``: the Cycles time of the model's Principled BSDF (about the same lobe count; thin coats and
  anisotropic stacks: set up from the same parameters) on the sphere scene, same samples and seed; None without a
  sphere scene;
* ``seconds``: the wall time of the preset's whole comparison.
"""
from __future__ import annotations

import html
import math

from .models import MODELS
from .nodes import FORM_LABELS
from .reference import metrics
from .reference import scenes as ref_scenes

LARGE_ERROR = 0.2  # relative RMSE above which the page names the approximations in use beside the error
PANEL_PX = 96  # CSS width of one panel in every picture, so that the columns of sphere and panorama strips line up
OVERVIEW = "overview.png"
OVERVIEW_GAP, OVERVIEW_COLUMN_GAP = 4, 12  # pixels between a column's strips, between the models' columns
TIMED_SCENE = "sphere"  # the scene whose render time is set against the Principled BSDF's
PICTURE_PANELS = ("Cycles", "reference", "error")  # the side-by-side picture of ``compare_core.compare``

STYLE = """
body{font-family:system-ui,sans-serif;background:#1e1e1e;color:#ddd;margin:24px;max-width:1300px;line-height:1.4}
a{color:#8cf} h1{margin-bottom:4px} h2{margin-top:40px;border-bottom:1px solid #555} h3{margin:28px 0 4px}
table{border-collapse:collapse;margin:8px 0} td,th{padding:3px 10px;text-align:left;vertical-align:middle}
th{background:#2c2c2c;font-weight:600} tr:nth-child(even) td{background:#242424}
td.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap} table.scenes th{white-space:nowrap}
td.large,td.large a{color:#ff9a5c;font-weight:600} tr.na td{color:#999;font-style:italic}
tbody.model tr:first-child td{border-top:2px solid #555}
img{image-rendering:pixelated;display:block} .meta{color:#aaa} .caption{color:#aaa;max-width:900px}
.columns{display:flex;margin-bottom:6px;font-size:14px;color:#bbb} .columns b{color:#ddd} td.nowrap{white-space:nowrap}
.legend{display:inline-block;margin:6px 0 16px} .ramp{height:16px;width:400px;border:1px solid #777}
.ticks{display:flex;justify-content:space-between;width:404px;font-size:13px;color:#bbb}
dl.scenes dt{font-weight:600;float:left;width:80px} dl.scenes dd{margin:0 0 6px 90px;max-width:900px}
.approx{background:#2a2420;border-left:3px solid #ff9a5c;padding:6px 12px;max-width:1000px}
.approx ul{margin:4px 0} .desc{color:#bbb;margin:2px 0 8px}
"""


def pct(x: float) -> str:
    """A relative error as a percentage: "n/a" for NaN (nothing to measure), "∞" for an error on a black reference."""
    if math.isnan(x):
        return "n/a"
    return "∞" if math.isinf(x) else f"{x:.1%}"


def seconds_text(s: float) -> str:
    """Seconds with three significant digits, so short times never read 0.00: "0.0123 s", "3.41 s", "118 s"."""
    return f"{s:.3g} s"


def clock(s: float) -> str:
    """Seconds as m:ss."""
    m, s = divmod(int(round(s)), 60)
    return f"{m}:{s:02d}"


def anchor(report: dict) -> str:
    """The id of the preset's section (model and preset names are identifiers)."""
    return f"{report['model']}-{report['label']}"


def worst(entries: dict) -> tuple[str, float] | None:
    """(scene, relative RMSE) of the scene with the largest error among a form's ``entries``; None if none is
    measurable."""
    errors = [(e["rel_rmse"], scene) for scene, e in entries.items() if not math.isnan(e["rel_rmse"])]
    if not errors:
        return None
    value, scene = max(errors)
    return scene, value


def forms_of(reports) -> list[str]:
    """The forms the reports compare, in the order they were run."""
    return list(dict.fromkeys(form for r in reports for form in r["forms"]))


def models_of(reports) -> list[str]:
    return list(dict.fromkeys(r["model"] for r in reports))


def timed(report: dict, form: str) -> float | None:
    """The form's Cycles time on ``TIMED_SCENE``, None if that scene was not rendered."""
    entry = report["forms"].get(form, {}).get(TIMED_SCENE)
    return None if entry is None else entry["cycles_seconds"]


def ratio_text(seconds: float | None, principled: float | None) -> str:
    if seconds is None:
        return "—"
    return seconds_text(seconds) + ("" if not principled else f" ({seconds / principled:.2g}×)")


# ------------------------------------------------------------------------------------------------ page


def index_html(reports, accuracy_href: str, date: str, overview_width: int) -> str:
    """The whole page. ``accuracy_href``: docs/accuracy.md relative to the page; ``overview_width``: the width in
    pixels of ``OVERVIEW`` (shown at ``PANEL_PX`` per panel)."""
    first = reports[0]
    parts = ["<h1>Lamina: every model against its reference</h1>",
             f'<p class="meta">{html.escape(date)} · {first["samples"]} samples per pixel · {first["resolution"]} '
             f"px · seed {first['seed']} · forms: {', '.join(FORM_LABELS[f] for f in forms_of(reports))} · "
             f"{len(reports)} presets in {clock(sum(r['seconds'] for r in reports))}</p>",
             _introduction(accuracy_href),
             _overview(reports, overview_width),
             _summary(reports),
             _reading(reports)]
    for model_id in models_of(reports):
        parts.append(f'<h2 id="{model_id}">{html.escape(MODELS[model_id].LABEL)}</h2>')
        parts += [_preset(r, accuracy_href) for r in reports if r["model"] == model_id]
    return ("<!doctype html><html lang=en><head><meta charset=utf-8><title>Lamina demo</title>"
            f"<style>{STYLE}</style></head><body>" + "\n".join(parts) + "</body></html>\n")


def _introduction(accuracy_href: str) -> str:
    link = f'<a href="{html.escape(accuracy_href)}">docs/accuracy.md</a>'
    return ("<p>Each preset of each model is rendered by Cycles in the forms above and by Lamina's exact reference "
            "(Python, float64) on the same scenes. <b>Relative RMSE</b> = root-mean-square difference ÷ the "
            "reference's mean over the object (0% = identical); it includes Cycles' sampling noise. "
            "<b>Mapping alone</b> is the error of the form's closures without any noise (what Cycles converges to "
            f"with infinite samples). Every approximation is named and measured on its own in {link} "
            f"(in the repository: <code>docs/accuracy.md</code>).</p>")


def overview_form(reports) -> str:
    """The form the overview shows: OSL (the closer one) where it was rendered."""
    forms = forms_of(reports)
    return "osl" if "osl" in forms else forms[0]


def overview_scene(report: dict, form: str) -> str | None:
    """The scene of the preset's strip in the overview: ``TIMED_SCENE``, else the first one rendered (None: none)."""
    entries = report["forms"].get(form, {})
    return TIMED_SCENE if TIMED_SCENE in entries else next(iter(entries), None)


def _overview(reports, overview_width: int) -> str:
    """The picture of pictures, under a header per column (the model, its presets top to bottom)."""
    form = overview_form(reports)
    scale = PANEL_PX / reports[0]["resolution"]
    shown = {m: [r["label"] for r in reports if r["model"] == m and overview_scene(r, form) is not None]
             for m in models_of(reports)}
    shown = {m: labels for m, labels in shown.items() if labels}
    column = (overview_width - (len(shown) - 1) * OVERVIEW_COLUMN_GAP) / len(shown) * scale
    headers = "".join(f'<div style="width:{column:.0f}px"><b>{html.escape(MODELS[m].LABEL)}</b><br>'
                      f'{html.escape(" · ".join(labels))}</div>' for m, labels in shown.items())
    scenes = " or ".join(dict.fromkeys(filter(None, (overview_scene(r, form) for r in reports))))
    return (f'<h2>Overview</h2><div class="columns" style="gap:{OVERVIEW_COLUMN_GAP * scale:.0f}px">{headers}</div>'
            f'<img id="overview" src="{OVERVIEW}" alt="every preset, {scenes} scene" '
            f'style="width:{overview_width * scale:.0f}px">'
            f'<p class="caption">One column per model, its presets top to bottom in the order above. Each strip is '
            f"{' | '.join(PICTURE_PANELS)} on the {scenes} scene, {FORM_LABELS[form]} form; the sections below "
            "show every scene and form.</p>")


def _summary(reports) -> str:
    forms = forms_of(reports)
    head = ("<tr><th>model</th><th>preset</th>"
            + "".join(f"<th>worst rel. RMSE, {FORM_LABELS[f]}</th>" for f in forms)
            + f"<th>{TIMED_SCENE}: Principled BSDF</th>"
            + "".join(f"<th>{TIMED_SCENE}: {FORM_LABELS[f]} (× Principled)</th>" for f in forms) + "</tr>")
    bodies = []
    for model_id in models_of(reports):
        rows = []
        for r in (r for r in reports if r["model"] == model_id):
            cells = [f"<td>{html.escape(MODELS[model_id].LABEL)}</td>",
                     f'<td><a href="#{anchor(r)}">{html.escape(r["label"])}</a></td>']
            cells += [_worst_cell(r, form) for form in forms]
            principled = r["principled_seconds"]
            cells.append(f'<td class="num">{"—" if principled is None else seconds_text(principled)}</td>')
            cells += [f'<td class="num">{ratio_text(timed(r, form), principled)}</td>' for form in forms]
            rows.append(f'<tr data-model="{model_id}" data-preset="{html.escape(r["label"])}">{"".join(cells)}</tr>')
        bodies.append('<tbody class="model">' + "".join(rows) + "</tbody>")
    return ('<h2>Summary</h2><table id="summary">' + head + "".join(bodies) + "</table>"
            f'<p class="caption">Worst: the largest relative RMSE over the scenes rendered (which one in brackets); '
            f"above {LARGE_ERROR:.0%} it is marked and links to the approximations in use. Times: one Cycles render "
            f"of the {TIMED_SCENE} scene each, the same samples and seed; the Principled BSDF has about the same "
            "number of lobes as the preset (thin coats: Blender's coat set up from the same parameters). Short "
            "renders are dominated by Cycles' own set-up time, so ratios near 1 mean little.</p>")


def _worst_cell(report: dict, form: str) -> str:
    found = worst(report["forms"].get(form, {}))
    if found is None:
        return '<td class="num">n/a</td>'
    scene, value = found
    return _error_cell(report, value, f"{pct(value)} ({scene})")


def _error_cell(report: dict, value: float, text: str) -> str:
    """A cell with a relative error; one above ``LARGE_ERROR`` is marked and links to the approximations in use."""
    if value > LARGE_ERROR:
        return f'<td class="num large"><a href="#{anchor(report)}-approx">{text} ▲</a></td>'
    return f'<td class="num">{text}</td>'


def _reading(reports) -> str:
    """The heat scale's legend and one sentence per scene the page shows."""
    stops = ", ".join(f"rgb({r * 255:.0f},{g * 255:.0f},{b * 255:.0f}) {pos:.0%}"
                      for pos, (r, g, b) in metrics.HEAT_STOPS)
    ticks = "".join(f"<span>{pos * metrics.HEAT_SCALE:.1%}</span>".replace(".0%", "%")
                    for pos, _ in metrics.HEAT_STOPS)
    shown = [s for s in ref_scenes.KINDS if any(s in entries for r in reports for entries in r["forms"].values())]
    notes = "".join(f"<dt>{s}</dt><dd>{html.escape(ref_scenes.NOTES[s])}</dd>" for s in shown)
    return ("<h2>Reading the pictures</h2>"
            f"<p>Every picture is {' | '.join(PICTURE_PANELS)} (models with a like-for-like Principled BSDF "
            "add it and its error). Both renders share one exposure. The error maps show |Cycles − reference| (the "
            "largest colour channel) as a share of the reference's mean over the object, on one fixed scale "
            "everywhere: pale yellow is "
            f"{metrics.HEAT_SCALE:.0%} or more; grey is outside the object.</p>"
            f'<div class="legend" id="heat-legend" data-scale="{metrics.HEAT_SCALE}">'
            f'<div class="ramp" style="background:linear-gradient(to right, {stops})"></div>'
            f'<div class="ticks">{ticks}</div>error ÷ reference mean</div>'
            f'<dl class="scenes" id="scenes">{notes}</dl>')


def _preset(report: dict, accuracy_href: str) -> str:
    """The preset's section: description, the approximations in use where an error is large, a row per scene and
    form (or one saying why a scene does not apply)."""
    entries = [e for by_scene in report["forms"].values() for e in by_scene.values()]
    principled = any("principled" in e for e in entries)
    panels = next((e["principled"]["panels"] for e in entries if "principled" in e), PICTURE_PANELS)
    widths = [70, 100, 90, 110] + ([120] if principled else []) + [80, 160, None]  # the same in every preset
    head = ("<colgroup>" + "".join(f'<col style="width:{w}px">' if w else "<col>" for w in widths) + "</colgroup>"
            + "<tr><th>scene</th><th>form</th><th>rel. RMSE</th><th>mapping alone</th>"
            + (f"<th>{html.escape(panels[2])} rel. RMSE</th>" if principled else "")  # principled_panels' label
            + f"<th>Cycles</th><th>reference</th><th>{html.escape(' | '.join(panels))}</th></tr>")
    rows = []
    rendered = {s for by_scene in report["forms"].values() for s in by_scene}
    for scene in [s for s in ref_scenes.KINDS if s in rendered or s in report["not_applicable"]]:
        if scene in report["not_applicable"]:
            rows.append(f'<tr class="na"><td class="scene">{scene}</td>'
                        f'<td colspan="{len(widths) - 1}">not applicable: '
                        f'{html.escape(report["not_applicable"][scene])}</td></tr>')
            continue
        rows += [_scene_row(report, form, scene, principled) for form, by_scene in report["forms"].items()
                 if scene in by_scene]
    large = any(e["rel_rmse"] > LARGE_ERROR for e in entries)
    return (f'<section class="preset" id="{anchor(report)}"><h3>{html.escape(report["label"])}</h3>'
            f'<p class="desc">{html.escape(report["description"])}</p>'
            + (_approximations(report, accuracy_href) if large else "")
            + '<table class="scenes">' + head + "".join(rows) + "</table></section>")


def _scene_row(report: dict, form: str, scene: str, principled: bool) -> str:
    e = report["forms"][form][scene]
    error = _error_cell(report, e["rel_rmse"], pct(e["rel_rmse"]))
    reference = "cached" if e["reference_cached"] else f"{seconds_text(e['reference_seconds'])} (computed)"
    picture = e["principled"]["files"]["principled_picture"] if principled else e["files"]["side_by_side"]
    n_panels = len(e["principled"]["panels"]) if principled else len(PICTURE_PANELS)
    src = html.escape(f"{report['dir']}/{picture}")
    return (f'<tr><td class="scene">{scene}</td><td class="nowrap">{FORM_LABELS[form]}</td>{error}'
            f'<td class="num">{pct(e["mapping_rel_rmse"])}</td>'
            + (f'<td class="num">{pct(e["principled"]["rel_rmse"])}</td>' if principled else "")
            + f'<td class="num">{seconds_text(e["cycles_seconds"])}</td><td class="num">{reference}</td>'
            f'<td><img src="{src}" alt="{scene}, {FORM_LABELS[form]}" style="width:{n_panels * PANEL_PX}px"></td></tr>')


def _approximations(report: dict, accuracy_href: str) -> str:
    items = "".join(f"<li><b>{html.escape(name)}</b>: {html.escape(what)}</li>"
                    for name, what in report["approximations"])
    return (f'<div class="approx" id="{anchor(report)}-approx">Errors above {LARGE_ERROR:.0%} (▲). The mapping\'s '
            f'approximations in use for this preset, each measured alone in <a href="{html.escape(accuracy_href)}">'
            f"docs/accuracy.md</a>:<ul>{items or '<li>none</li>'}</ul>Where <i>mapping alone</i> stays low, the "
            "error is Cycles' sampling noise instead (more samples lower it).</div>")


# ------------------------------------------------------------------------------------------------ console


def time_left(reports, remaining_models) -> float:
    """Seconds the presets still to run (their model ids) should take: each at the mean time of its model's presets
    so far, or of all presets so far for a model not started yet."""
    overall = sum(r["seconds"] for r in reports) / len(reports)

    def mean(model_id):
        times = [r["seconds"] for r in reports if r["model"] == model_id]
        return sum(times) / len(times) if times else overall

    return sum(mean(m) for m in remaining_models)


def progress_line(done: int, total: int, report: dict, elapsed: float, left: float) -> str:
    """``lamina: [3/9] thin_coat glazed_ceramic 11.2 s (elapsed 0:41, about 1:50 left)``."""
    return (f"lamina: [{done}/{total}] {report['model']} {report['label']} {report['seconds']:.1f} s "
            f"(elapsed {clock(elapsed)}, about {clock(left)} left)")


def summary_lines(reports) -> list[str]:
    """One line per preset: the worst error of each form and the timed scene against the Principled BSDF."""
    lines = []
    for r in reports:
        worst_text = []
        for form, entries in r["forms"].items():
            found = worst(entries)
            worst_text.append(f"{FORM_LABELS[form]} n/a" if found is None
                              else f"{FORM_LABELS[form]} {pct(found[1])} ({found[0]})")
        times = ", ".join(f"{FORM_LABELS[f]} {ratio_text(timed(r, f), r['principled_seconds'])}" for f in r["forms"])
        lines.append(f"lamina: {r['model']} {r['label']}: worst {', '.join(worst_text)}"
                     + (f"; {TIMED_SCENE} {times}" if r["principled_seconds"] is not None else ""))
    return lines
