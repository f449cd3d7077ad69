"""The benchmark pages keep each model's sections between markers, so ``bench --model`` replaces one model's numbers
without touching the others'."""
from addon import bench


def test_splice_replaces_only_the_named_models_section():
    page = "# Accuracy\n" + bench.marked("a", "\n# A\nold a\n") + bench.marked("b", "# B\nold b")
    new = bench.splice(page, "a", "# A\nnew a\n", "*again*")
    assert "new a" in new and "old a" not in new and "*again*" in new
    assert new.endswith(bench.marked("b", "# B\nold b")) and new.startswith("# Accuracy\n")
    assert bench.splice(new, "a", "# A\nnewer", "*again*").count("<!-- lamina-bench a -->") == 1


def test_a_model_new_since_the_last_whole_run_is_appended():
    page = "# Accuracy\n" + bench.marked("a", "# A\nold a")
    new = bench.splice(page, "b", "# B\nnew b", "*alone*")
    assert new.startswith(page.rstrip("\n")) and new.count("<!-- lamina-bench b -->") == 1
    assert "new b" in new and "*alone*" in new and "old a" in new


def test_the_closure_budget_section_lists_only_presets_whose_fit_misses_a_goal(monkeypatch):
    """``bench.fit_ceiling`` refits only where the shipped fitted mapping misses one of issue 14's goals (a backlit
    scene counts only where the reference reaches the threshold); its rows say n/a where a scene does not count."""
    from addon.bench import fit_ceiling
    from addon.nodes import choice

    fine = {"sphere": 0.05, "plane": 0.05, "backlit": 0.9, "furnace": 0.01}  # backlit black: does not count
    means = {"sphere": 0.01, "plane": 0.01, "backlit": 0.0, "furnace": 0.1}
    missed = {**fine, "plane": 0.3}

    def choose(model_id, p, form, mapping):
        errors = missed if model_id == "spongecake" and p.to_dict() == spongecake_sheen else fine
        return choice.Choice("fitted", None, {"fitted": errors}, means=means)

    from addon import presets
    from addon.models import spongecake

    spongecake_sheen = spongecake.params_from_dict(presets.load("spongecake", "sheen")).to_dict()
    monkeypatch.setattr(choice, "choose", choose)
    monkeypatch.setattr(fit_ceiling, "ceiling_rows", lambda model_id, p, resolution: [
        {"spare": n, "closures": 2 + i, "fit_error": 0.4 - 0.1 * i, "errors": missed, "means": means}
        for i, n in enumerate((*fit_ceiling.SPARE, fit_ceiling.EVERY))])
    section = fit_ceiling.accuracy(bench.Sizes(resolution=8))
    rows = [line for line in section.splitlines() if line.startswith("| spongecake") or line.startswith("| thin")]
    assert rows == [f"| spongecake | sheen | {n} | {2 + i} | {40 - 10 * i:.1f}% | 5.0% | 30.0% | n/a | 1.0% |"
                    for i, n in enumerate((*fit_ceiling.SPARE, fit_ceiling.EVERY))]
    assert fit_ceiling.misses_a_goal(missed, means) and not fit_ceiling.misses_a_goal(fine, means)


def test_a_section_measured_alone_replaces_only_itself(tmp_path):
    """``splice_alone`` (``python -m addon.bench.budget``, ``fit_ceiling``, ``bake_speed``) rewrites its own section of
    an existing page and says it was measured alone."""
    page = "# Benchmarks\n" + bench.marked("a", "old a") + bench.marked("b", "old b")
    (tmp_path / "benchmarks.md").write_text(page, encoding="utf-8")
    bench.splice_alone(str(tmp_path), "benchmarks.md", "b", "new b", "python -m x")
    new = (tmp_path / "benchmarks.md").read_text(encoding="utf-8")
    assert "old a" in new and "new b" in new and "old b" not in new
    assert "measured alone (`python -m x`" in new


def test_the_bake_speed_section_names_the_network_it_timed(tmp_path):
    """The bake's throughput depends on the network's width, so its section says which network ran; measured alone
    it lands in its own section of the page, after the others."""
    from addon.bake import spongecake as ms
    from addon.bench import bake_speed

    widths = " × ".join(str(w) for w in ms.network(2).hidden)
    section = bake_speed.speed(4)  # a real bake of 4×4 texels
    assert f"hidden {widths}" in section and "s per megapixel**" in section
    (tmp_path / "benchmarks.md").write_text("# Benchmarks\n" + bench.marked("spongecake", "renders"), encoding="utf-8")
    assert bake_speed.main(["--out", str(tmp_path), "--size", "4"]) == 0
    page = (tmp_path / "benchmarks.md").read_text(encoding="utf-8")
    assert page.index("renders") < page.index("<!-- lamina-bench bake-speed -->") < page.index("s per megapixel")
