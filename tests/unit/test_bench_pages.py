"""The benchmark pages keep each model's sections between markers, so ``bench --model`` replaces one model's numbers
without touching the others'."""
import pytest

from addon import bench


def test_splice_replaces_only_the_named_models_section():
    page = "# Accuracy\n" + bench.marked("a", "\n# A\nold a\n") + bench.marked("b", "# B\nold b")
    new = bench.splice(page, "a", "# A\nnew a\n", "*again*")
    assert "new a" in new and "old a" not in new and "*again*" in new
    assert new.endswith(bench.marked("b", "# B\nold b")) and new.startswith("# Accuracy\n")
    assert bench.splice(new, "a", "# A\nnewer", "*again*").count("<!-- lamina-bench a -->") == 1


def test_splice_refuses_a_page_without_the_models_section():
    with pytest.raises(ValueError, match="run the whole `make bench` first"):
        bench.splice("# Accuracy\n", "a", "x", "note")
