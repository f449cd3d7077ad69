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
