"""The headless CLI for thin coats: presets listed, materials written from a preset or a JSON dict, and every bad
input refused before any work with exit code 2 and one line (``python -m addon.cli``, the same code as
``blender -c lamina``)."""
import json
import os
import subprocess
import sys

import pytest

from addon import presets
from addon.models import thin_coat as model

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def lamina(*args):
    return subprocess.run([sys.executable, "-m", "addon.cli", *args], capture_output=True, text=True, cwd=ROOT,
                          env=dict(os.environ, PYTHONPATH=ROOT), timeout=300)




def test_list_presets_prints_the_six_with_their_descriptions():
    r = lamina("list-presets", "--model", "thin_coat")
    assert r.returncode == 0 and r.stderr == ""
    lines = r.stdout.splitlines()
    assert [line.split()[0] for line in lines] == presets.names(model.ID)
    column = {line.index(presets.description(model.ID, line.split()[0])) for line in lines}
    assert len(column) == 1  # descriptions start in one column, the longest name included


@pytest.mark.parametrize("form", ["nodes", "osl"])
def test_make_material_from_a_preset(tmp_path, form):
    out = tmp_path / "lacquer.blend"
    r = lamina("make-material", "--model", "thin_coat", "--preset", "amber_lacquer", "--form", form, "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert out.read_bytes()[:7] == b"BLENDER" and [p.name for p in tmp_path.iterdir()] == ["lacquer.blend"]


def test_make_material_from_a_json_dict_with_roughness_and_a_clamp_warning(tmp_path):
    d = {"roughness_top": 0.1, "kappa_bottom": 500, "eta": 1.5, "sigma_a": [0.1, 0.2, 0.4], "depth": 0.5,
         "bounces": 9, "base": {"type": "conductor"}}
    (tmp_path / "coat.json").write_text(json.dumps(d))
    r = lamina("make-material", "--model", "thin_coat", "--json", str(tmp_path / "coat.json"), "--out",
               str(tmp_path / "coat.blend"))
    assert r.returncode == 0, r.stderr
    assert "lamina: warning: thin_coat: bounces: 9 is outside [0, 4], clamped to 4" in r.stderr
    assert (tmp_path / "coat.blend").read_bytes()[:7] == b"BLENDER"


BAD_JSON = [
    ({"bounces": 1.5}, "thin_coat: bounces: expected a whole number, got 1.5"),
    ({"kappa_top": 10, "roughness_top": 0.2}, "give either kappa_top or roughness_top"),
    ({"base": {"type": "wood"}}, "base: expected a dict with type in dielectric_rough, conductor, diffuse, slab"),
    ({"sigma_a": [0.1, 0.2]}, "sigma_a: expected three numbers"),
    ({"thickness": 2}, "unknown key(s) thickness"),
    ([0.1, 0.2], "expected a dict"),
]


@pytest.mark.parametrize("data, reason", BAD_JSON, ids=[r for _, r in BAD_JSON])
def test_bad_json_exits_2_with_one_line_and_writes_nothing(tmp_path, data, reason):
    (tmp_path / "coat.json").write_text(json.dumps(data))
    for command in ("make-material", "compare"):
        r = lamina(command, "--model", "thin_coat", "--json", str(tmp_path / "coat.json"), "--out",
                   str(tmp_path / "out"))
        assert r.returncode == 2, r.stderr
        assert r.stderr.strip().count("\n") == 0 and reason in r.stderr and r.stderr.startswith("lamina: error: ")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["coat.json"]


def test_truth_settings_are_checked_before_any_work(tmp_path):
    r = lamina("compare", "--model", "thin_coat", "--preset", "amber_lacquer", "--truth", "--truth-paths", "3",
               "--out", str(tmp_path / "x"))
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0
    assert "paths must be ≥ 16" in r.stderr and not (tmp_path / "x").exists()


def test_unknown_model_is_a_usage_error():
    r = lamina("list-presets", "--model", "velvet")
    assert r.returncode == 2 and "thin_coat" in r.stderr  # argparse lists the choices


def test_make_material_and_compare_take_the_mapping(tmp_path):
    """``--mapping fitted`` says which mapping renders and both predicted errors; compare reports them per form."""
    out = tmp_path / "lacquer.blend"
    r = lamina("make-material", "--model", "thin_coat", "--preset", "amber_lacquer", "--mapping", "fitted", "--out",
               str(out))
    assert r.returncode == 0, r.stderr
    assert "lamina: fitted mapping (predicted mean rel. RMSE on the comparison scenes: analytic" in r.stdout
    r = lamina("compare", "--model", "thin_coat", "--preset", "amber_lacquer", "--mapping", "auto", "--forms",
               "nodes,osl", "--scenes", "sphere", "--resolution", "16", "--samples", "4", "--out",
               str(tmp_path / "cmp"))
    assert r.returncode == 0, r.stderr
    report = json.loads((tmp_path / "cmp" / "report.json").read_text())
    assert report["mapping"] == "auto"
    for form in ("nodes", "osl"):
        m = report["mappings"][form]
        assert m["used"] in ("analytic", "fitted") and set(m["predicted_error"]) == {"analytic", "fitted"}
        assert f"{form:5s} {m['used']} mapping" in r.stdout


def test_the_mapping_is_refused_where_a_model_has_no_fitted_one(tmp_path):
    r = lamina("compare", "--model", "micrograin", "--preset", "rust_on_metal", "--mapping", "fitted", "--out",
               str(tmp_path / "x"))
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == ["lamina: error: --mapping: model micrograin has only its analytic "
                                             "mapping (models with a fitted one: spongecake, thin_coat)"]
    r = lamina("make-material", "--model", "thin_coat", "--preset", "amber_lacquer", "--mapping", "exact", "--out",
               str(tmp_path / "x.blend"))
    assert r.returncode == 2 and "--mapping: invalid choice: 'exact'" in r.stderr
